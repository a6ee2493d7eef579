// The one wall-clock stamp: the time now in UTC, strftime-formatted (report
// headers, report directory names, the journal's start).
#pragma once

#include <string>

namespace mbc::conf {

inline constexpr const char* kIsoUtc = "%Y-%m-%dT%H:%M:%SZ";  // ISO 8601, e.g. 2026-12-04T10:24:40Z

std::string utc_now(const char* format = kIsoUtc);

}  // namespace mbc::conf
