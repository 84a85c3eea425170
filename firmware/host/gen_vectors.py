#!/usr/bin/env python3
"""Turn tests/vectors/protocol.json into a C++ header for the host tests (build time only).

Usage: gen_vectors.py protocol.json > vectors.h. Fails on a field or type the firmware's
structs do not have, so the JSON and the C++ structs cannot drift apart silently.
"""

from __future__ import annotations

import json
import sys

FIELDS: dict[str, dict[str, str]] = {
    "command": {
        "to_node": "uint8_t",
        "from_node": "uint8_t",
        "seq": "uint16_t",
        "velocity_mm_s": "uint16_t",
        "direction": "uint8_t",
        "flags": "uint8_t",
        "ttl_ms": "uint16_t",
    },
    "telemetry": {
        "to_node": "uint8_t",
        "from_node": "uint8_t",
        "seq": "uint16_t",
        "echo_seq": "uint16_t",
        "robot_clock_ms": "uint32_t",
        "velocity_mm_s": "uint16_t",
        "direction": "uint8_t",
        "battery_10mv": "uint16_t",
        "lat_e7": "int32_t",
        "lon_e7": "int32_t",
        "fix_quality": "uint8_t",
        "satellites": "uint8_t",
        "status": "uint8_t",
        "rssi_dbm": "int8_t",
    },
    "config": {
        "to_node": "uint8_t",
        "from_node": "uint8_t",
        "seq": "uint16_t",
        "max_velocity_mm_s": "uint16_t",
        "accel_mm_s2": "uint16_t",
    },
    "config_ack": {
        "to_node": "uint8_t",
        "from_node": "uint8_t",
        "seq": "uint16_t",
        "max_velocity_mm_s": "uint16_t",
        "accel_mm_s2": "uint16_t",
        "hard_max_velocity_mm_s": "uint16_t",
    },
    "identify": {
        "to_node": "uint8_t",
        "from_node": "uint8_t",
        "seq": "uint16_t",
    },
    "identity": {
        "to_node": "uint8_t",
        "from_node": "uint8_t",
        "seq": "uint16_t",
        "build_id": "char[17]",
        "hard_max_velocity_mm_s": "uint16_t",
        "max_velocity_mm_s": "uint16_t",
        "accel_mm_s2": "uint16_t",
        "accel_min_mm_s2": "uint16_t",
        "accel_max_mm_s2": "uint16_t",
        "stop_decel_mm_s2": "uint16_t",
        "dead_man_ms": "uint16_t",
        "reverse_dwell_ms": "uint16_t",
        "full_scale_mm_s": "uint16_t",
        "low_battery_10mv": "uint16_t",
        "gps_stale_ms": "uint16_t",
        "battery_median_window": "uint8_t",
    },
}
FRAME_TYPE = {
    "command": "FRAME_COMMAND",
    "telemetry": "FRAME_TELEMETRY",
    "config": "FRAME_CONFIG",
    "config_ack": "FRAME_CONFIG_ACK",
    "identify": "FRAME_IDENTIFY",
    "identity": "FRAME_IDENTITY",
}
ERRORS = {
    "too_short",
    "length_mismatch",
    "reserved_bits",
    "unknown_version",
    "unknown_type",
    "size_mismatch",
    "out_of_range",
    "bad_enum",
}


def c_string(text: str) -> str:
    return json.dumps(text, ensure_ascii=True)


def c_bytes(name: str, hex_text: str) -> tuple[str, int]:
    data = bytes.fromhex(hex_text)
    body = ", ".join(f"0x{b:02x}" for b in data) or "0x00"
    return f"static const uint8_t {name}[] = {{{body}}};", len(data)


def main(path: str) -> int:
    with open(path, encoding="utf-8") as handle:
        doc = json.load(handle)
    out = [
        "// Generated from tests/vectors/protocol.json by firmware/host/gen_vectors.py.",
        "// Do not edit and do not commit.",
        "#ifndef AMZ_VECTORS_H",
        "#define AMZ_VECTORS_H",
        "#include <stddef.h>",
        "#include <stdint.h>",
        "#include <string.h>",
        '#include "protocol.h"',
        "namespace vectors {",
        "struct Valid { const char* name; const uint8_t* bytes; size_t len;"
        " void (*fill)(amz::Frame*); };",
        "struct Malformed { const char* name; const uint8_t* bytes; size_t len;"
        " const char* error; };",
    ]
    valid_rows = []
    for index, vector in enumerate(doc["valid"]):
        kind = vector["type"]
        if kind not in FIELDS:
            raise SystemExit(f"{vector['name']}: unknown frame type {kind!r}")
        fields = vector["fields"]
        if set(fields) != set(FIELDS[kind]):
            raise SystemExit(
                f"{vector['name']}: fields {sorted(fields)} differ from {sorted(FIELDS[kind])}"
            )
        array, length = c_bytes(f"valid_{index}", vector["hex"])
        out.append(array)
        out.append(f"static void fill_valid_{index}(amz::Frame* f) {{")
        out.append(f"  f->type = amz::{FRAME_TYPE[kind]};")
        for field, ctype in FIELDS[kind].items():
            if ctype.startswith("char["):
                # A text field: the string, NUL-padded to its array (memset by the caller).
                text = str(fields[field])
                if len(text) >= int(ctype[5:-1]) or not text.isascii():
                    raise SystemExit(f"{vector['name']}: {field} does not fit {ctype}")
                out.append(f"  strcpy(f->{kind}.{field}, {c_string(text)});")
            else:
                out.append(f"  f->{kind}.{field} = static_cast<{ctype}>({int(fields[field])}LL);")
        out.append("}")
        valid_rows.append(
            f"  {{{c_string(vector['name'])}, valid_{index}, {length}, &fill_valid_{index}}},"
        )
    malformed_rows = []
    for index, vector in enumerate(doc["malformed"]):
        if vector["error"] not in ERRORS:
            raise SystemExit(f"{vector['name']}: unknown error kind {vector['error']!r}")
        array, length = c_bytes(f"malformed_{index}", vector["hex"])
        out.append(array)
        malformed_rows.append(
            f"  {{{c_string(vector['name'])}, malformed_{index}, {length},"
            f" {c_string(vector['error'])}}},"
        )
    out.append("static const Valid kValid[] = {")
    out.extend(valid_rows)
    out.append("};")
    out.append("static const Malformed kMalformed[] = {")
    out.extend(malformed_rows)
    out.append("};")
    out.append(f"static const size_t kValidCount = {len(valid_rows)};")
    out.append(f"static const size_t kMalformedCount = {len(malformed_rows)};")
    out.append("}  // namespace vectors")
    out.append("#endif")
    print("\n".join(out))
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit("usage: gen_vectors.py protocol.json > vectors.h")
    sys.exit(main(sys.argv[1]))
