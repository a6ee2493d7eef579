// junit.xml agrees with the exit code: a failed SHOULD is no <failure>
// unless --fail-on should; classnames are dotted identifiers, whatever the
// device or suite is called (the client suite's names have spaces and dots).
#include <gtest/gtest.h>

#include <regex>

#include "report/report.h"

namespace mbc::conf {
namespace {

RunReport one_should_failure(const std::string& device) {
  RunReport rep;
  rep.command = "run";
  DeviceRun d;
  d.device_id = device;
  CaseResult pass;
  pass.id = "x/registers/0x0000/read";
  pass.family = "registers";
  pass.outcome = Outcome::pass;
  CaseResult should;
  should.id = "x/standard/fc43/bad-read-device-id-code";
  should.family = "standard";
  should.level = Level::should;
  should.outcome = Outcome::fail;
  should.message = "answered 2B 0E with data";
  d.cases = {pass, should};
  rep.devices.push_back(d);
  return rep;
}

size_t occurrences(const std::string& s, const std::string& what) {
  size_t n = 0;
  for (size_t at = s.find(what); at != std::string::npos; at = s.find(what, at + 1)) ++n;
  return n;
}

TEST(Junit, AFailedShouldIsNoFailureUnlessFailOnShould) {
  RunReport rep = one_should_failure("hsc60");
  std::string x = junit_xml(rep);
  EXPECT_EQ(occurrences(x, "<failure"), 0u) << x;
  EXPECT_NE(x.find("failures=\"0\""), std::string::npos) << x;
  EXPECT_NE(x.find("--fail-on should"), std::string::npos) << x;  // the output says how to make it one
  rep.fail_on_should = true;
  x = junit_xml(rep);
  EXPECT_EQ(occurrences(x, "<failure"), 1u) << x;
  EXPECT_NE(x.find("type=\"SHOULD\""), std::string::npos) << x;
  EXPECT_EQ(occurrences(x, "failures=\"1\""), 2u) << x;  // <testsuites> and <testsuite>
}

TEST(Junit, ClassnamesAreDottedIdentifiers) {
  std::string x = junit_xml(one_should_failure("libmodbus 3.1.10 (pty, rtu)"));
  std::regex classname("classname=\"([^\"]*)\"");
  size_t n = 0;
  for (auto it = std::sregex_iterator(x.begin(), x.end(), classname); it != std::sregex_iterator(); ++it, ++n)
    EXPECT_TRUE(std::regex_match((*it)[1].str(), std::regex("[A-Za-z_][A-Za-z0-9_]*(\\.[A-Za-z_][A-Za-z0-9_]*)+"))) << (*it)[1];
  EXPECT_EQ(n, 2u);
  EXPECT_EQ(junit_classname("sihong-57hs-r", "function-codes"), "mbconform.sihong_57hs_r.function_codes");
}

}  // namespace
}  // namespace mbc::conf
