"""What the physical-world tests share: skip with the reason where MuJoCo cannot render
(never in CI: ``.ci/run`` installs EGL and Mesa, and sets ``OVIS_REQUIRE_PHYSICAL``, which
turns the skip into a failure)."""

from __future__ import annotations

import os

import pytest

from ovis.common.physical.availability import why_unavailable

REASON = why_unavailable()

#: Mark a test (or a module, as ``pytestmark``) that needs the physical world.
needs_physical = pytest.mark.skipif(
    REASON is not None and not os.environ.get("OVIS_REQUIRE_PHYSICAL"),
    reason=f"physical world unavailable: {REASON}",
)
