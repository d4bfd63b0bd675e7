"""The rmw_zenoh wire layout as its design document states it, quoted word for word,
for the tests to check ovis's keys, tokens and attachments against.

Source: repository ros2/rmw_zenoh, path docs/design.md, commit
99a6a2bd10b949052f4f12c5854825dc005e95a5 (sections "Topic and Service name mapping to
Zenoh key expressions", "Graph Cache", "Publishers").
"""

from __future__ import annotations

import re

SOURCE = "ros2/rmw_zenoh docs/design.md @ 99a6a2bd10b949052f4f12c5854825dc005e95a5"

KEY_FORMAT = "`<domain_id>/<fully_qualified_name>/<type_name>/<type_hash>`"
KEY_EXAMPLES = {
    # (domain, fully qualified name, type, hash) → the key, as the document shows it
    (0, "/chatter", "std_msgs/msg/String"): (
        "0/chatter/std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    ),
    (0, "/robot1/chatter", "std_msgs/msg/String"): (
        "0/robot1/chatter/std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    ),
}
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"

NODE_TOKEN_FORMAT = (
    "@ros2_lv/<domain_id>/<session_id>/<node_id>/<node_id>/<entity_kind>/<mangled_enclave>/"
    "<mangled_namespace>/<node_name>"
)
ENTITY_TOKEN_FORMAT = (
    "@ros2_lv/<domain_id>/<session_id>/<node_id>/<entity_id>/<entity_kind>/<mangled_enclave>/"
    "<mangled_namespace>/<node_name>/<mangled_qualified_name>/<type_name>/<type_hash>/<qos>"
)
MANGLING = "A mangled name is the name with each `/` characters replaced by `%`"
NODE_EXAMPLE = "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
PUBLISHER_EXAMPLE = (
    "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
    "std_msgs::msg::dds_::String_/"
    "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,7:,:,:,,"
)
SUBSCRIPTION_EXAMPLE = (
    "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/"
    "std_msgs::msg::dds_::String_/"
    "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,10:,:,:,,"
)
ATTACHMENT = """\
  * 8 bytes for the sequence number (int64_t), encoded as a little-endian
  * 8 bytes for the timestamp (number of ns since UNIX EPOCH as int64_t), encoded as a little-endian
  * 1 byte for the length of the publisher GID (currently always 16)
  * 16 bytes for the publisher GID (array of 16 int8_t)"""

# The formats above as patterns: a placeholder is one chunk of a key (no '/').
_CHUNK = r"([^/]+)"


def _pattern(fmt: str) -> re.Pattern[str]:
    text = re.sub(r"<[a-z_]+>", "\x00", fmt.strip("`"))
    return re.compile(re.escape(text).replace("\x00", _CHUNK))


NODE_TOKEN = _pattern(NODE_TOKEN_FORMAT)
ENTITY_TOKEN = _pattern(ENTITY_TOKEN_FORMAT)
#: a data key: the domain, then the fully qualified name without its leading '/' (one or
#: more chunks), then the DDS type name and the RIHS01 hash
DATA_KEY = re.compile(r"(\d+)/(.+)/([^/]+::msg::dds_::[^/]+_)/(RIHS01_[0-9a-f]{64})")
