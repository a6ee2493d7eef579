// Serial logs: one frame per line, timestamped hex (README.md, "Serial
// logs"), the format `mbconform serve --trace` writes:
//
//   2026-12-01T22:54:29.123456Z pty /tmp/ttyMB0 rx 01 03 00 00 00 01 84 0A | slave 1 FC 03 ...
//   TIME [LINK ...] rx|tx HEX [| comment]
//
// TIME is ISO 8601 UTC with up to 9 fraction digits, or seconds as a decimal
// number (relative logs); LINK names the line or connection (optional);
// rx is a frame the device received (a request), tx one it sent (a reply);
// "--" lines and lines with a time but no direction are events, skipped.
#pragma once
#include <cstdint>
#include <cstdio>
#include <optional>
#include <string_view>

#include "capture/frames.h"

namespace mbc::conf::capture {

// Microseconds since the Unix epoch (ISO form) or since 0 (seconds form).
std::optional<uint64_t> parse_log_time(std::string_view token);
// Reads lines from `f` (not closed) until its end; lines longer than 64 KiB
// and lines not in the format are findings.
ReadStats read_serial_log(FILE* f, FrameSink& sink);

}  // namespace mbc::conf::capture
