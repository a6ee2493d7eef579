// The one wall-clock stamp (report/utc_now.h): read back with strptime and
// timegm (the C library, not the code under test), it names a second between
// the time before and after the call, in UTC whatever the local zone.
#include <gtest/gtest.h>

#include <cstdlib>
#include <ctime>
#include <regex>
#include <string>

#include "report/utc_now.h"

TEST(UtcNow, IsIsoUtcOfNowWhateverTheLocalZone) {
  setenv("TZ", "Asia/Shanghai", 1);  // UTC+8: a local time would be 8 hours off
  tzset();
  const std::time_t before = std::time(nullptr);
  const std::string s = mbc::conf::utc_now();
  const std::time_t after = std::time(nullptr);
  ASSERT_TRUE(std::regex_match(s, std::regex(R"(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ)"))) << s;
  std::tm tm{};
  ASSERT_NE(strptime(s.c_str(), "%Y-%m-%dT%H:%M:%SZ", &tm), nullptr) << s;
  const std::time_t read_back = timegm(&tm);
  EXPECT_GE(read_back, before) << s;
  EXPECT_LE(read_back, after) << s;
  unsetenv("TZ");
  tzset();
}

TEST(UtcNow, TakesTheFormatOfADirectoryName) {
  const std::string s = mbc::conf::utc_now("%Y%m%dT%H%M%SZ");
  EXPECT_TRUE(std::regex_match(s, std::regex(R"(\d{8}T\d{6}Z)"))) << s;
}
