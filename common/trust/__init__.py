"""Proof of origin: Ed25519 keys kept in files, and the proof a message carries in its
Zenoh attachment (who signed it, a signature over its key expression and exact payload
bytes), so that a consumer believes only what the stage that holds the key published.

May import: atomic, config.
"""
