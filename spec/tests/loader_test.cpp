// The loader against hand-written malformed specs. Each fixture in
// malformed/ starts with the diagnostic it must produce:
//   # expect: LINE:COL RULE: MESSAGE-SUBSTRING
// and the loader must report exactly that location and rule.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>

#include "erratum_extra.h"
#include "loader.h"

namespace fs = std::filesystem;
using mbc::spec::load_spec_file;
using mbc::spec::load_spec_text;

namespace {

std::vector<fs::path> files_in(const std::string& sub) {
  std::vector<fs::path> v;
  for (const auto& e : fs::directory_iterator(fs::path(MBCONFORM_TEST_DIR) / sub))
    if (e.path().extension() == ".yaml") v.push_back(e.path());
  std::sort(v.begin(), v.end());
  return v;
}

struct Expectation {
  int line = 0, col = 0;
  std::string rule, message;
};

std::optional<Expectation> expectation_of(const fs::path& p) {
  std::ifstream in(p);
  std::string first;
  std::getline(in, first);
  static const std::regex re(R"(^# expect: (\d+):(\d+) ([a-z-]+): (.*)$)");
  std::smatch m;
  if (!std::regex_match(first, m, re)) return std::nullopt;
  return Expectation{std::stoi(m[1]), std::stoi(m[2]), m[3], m[4]};
}

}  // namespace

TEST(Loader, HasAtLeastFortyMalformedFixtures) { EXPECT_GE(files_in("malformed").size(), 40u); }

class Malformed : public ::testing::TestWithParam<fs::path> {};

TEST_P(Malformed, ReportsTheExpectedRuleAtTheExpectedPlace) {
  auto exp = expectation_of(GetParam());
  ASSERT_TRUE(exp) << GetParam() << ": first line must be '# expect: LINE:COL RULE: MESSAGE'";
  auto r = load_spec_file(GetParam().string());
  EXPECT_FALSE(r.ok());
  std::string all;
  bool found = false;
  for (const auto& d : r.diagnostics) {
    all += "\n  " + d.str();
    if (d.line == exp->line && d.col == exp->col && d.rule == exp->rule && d.message.find(exp->message) != std::string::npos)
      found = true;
    EXPECT_EQ(d.file, GetParam().string());
  }
  EXPECT_TRUE(found) << "expected " << exp->line << ":" << exp->col << " " << exp->rule << ": " << exp->message
                     << "\ngot:" << all;
}

INSTANTIATE_TEST_SUITE_P(Fixtures, Malformed, ::testing::ValuesIn(files_in("malformed")),
                         [](const auto& info) {
                           std::string n = info.param.stem().string();
                           for (char& c : n)
                             if (!isalnum(static_cast<unsigned char>(c))) c = '_';
                           return n;
                         });

class Valid : public ::testing::TestWithParam<fs::path> {};

TEST_P(Valid, LoadsWithoutDiagnostics) {
  auto r = load_spec_file(GetParam().string());
  std::string all;
  for (const auto& d : r.diagnostics) all += "\n  " + d.str();
  EXPECT_TRUE(r.ok()) << all;
}

INSTANTIATE_TEST_SUITE_P(Fixtures, Valid, ::testing::ValuesIn(files_in("valid")),
                         [](const auto& info) {
                           std::string n = info.param.stem().string();
                           for (char& c : n)
                             if (!isalnum(static_cast<unsigned char>(c))) c = '_';
                           return n;
                         });

// The loader is fuzzed; these are the shapes that break naive YAML loaders.
TEST(Loader, DeepFlowNestingIsRejectedNotACrash) {
  std::string text = "mbconform_spec: " + std::string(100000, '[') + std::string(100000, ']');
  auto r = load_spec_text(text, "deep.yaml");
  ASSERT_FALSE(r.diagnostics.empty());
  EXPECT_EQ(r.diagnostics[0].rule, "yaml");
  EXPECT_NE(r.diagnostics[0].message.find("nesting"), std::string::npos);
}

TEST(Loader, DeepBlockNestingIsRejectedNotACrash) {
  std::string text;
  for (int i = 0; i < 5000; ++i) text += std::string(size_t(i), ' ') + "k:\n";
  auto r = load_spec_text(text, "deep-block.yaml");
  ASSERT_FALSE(r.diagnostics.empty());
  EXPECT_EQ(r.diagnostics[0].rule, "yaml");
}

TEST(Loader, DeepSequenceMarkersAreRejected) {
  std::string text = "x: ";
  for (int i = 0; i < 5000; ++i) text += "- ";
  text += "1\n";
  auto r = load_spec_text(text, "dashes.yaml");
  ASSERT_FALSE(r.diagnostics.empty());
  EXPECT_EQ(r.diagnostics[0].rule, "yaml");
}

TEST(Loader, AliasBombIsBounded) {
  std::string text = "a: &a [x, x, x, x, x, x, x, x, x, x]\n";
  char prev = 'a';
  for (char c = 'b'; c <= 'k'; ++c, ++prev)
    text += std::string(1, c) + ": &" + c + " [*" + prev + ", *" + prev + ", *" + prev + ", *" + prev + ", *" + prev +
            ", *" + prev + ", *" + prev + ", *" + prev + ", *" + prev + ", *" + prev + "]\n";
  auto r = load_spec_text(text, "bomb.yaml");
  ASSERT_FALSE(r.diagnostics.empty());
  EXPECT_EQ(r.diagnostics[0].rule, "yaml");
  EXPECT_NE(r.diagnostics[0].message.find("too large"), std::string::npos);
}

TEST(Loader, BinaryGarbageIsAnError) {
  std::string text("\x00\xff\xfe garbage", 12);
  auto r = load_spec_text(text, "bin.yaml");
  ASSERT_FALSE(r.diagnostics.empty());
}

TEST(Loader, MissingFileIsAnIoError) {
  auto r = load_spec_file("/nonexistent/spec.yaml");
  ASSERT_EQ(r.diagnostics.size(), 1u);
  EXPECT_EQ(r.diagnostics[0].rule, "io");
  EXPECT_EQ(r.diagnostics[0].str(), "/nonexistent/spec.yaml:0:0: error: io: cannot open the file");
}

TEST(Loader, FrameFormatsAreStringsNotFloats) {
  // YAML 1.2 would read 8E1 as 80.0; the language reads it as a frame format.
  auto r = load_spec_file((fs::path(MBCONFORM_TEST_DIR) / "valid" / "minimal.yaml").string());
  ASSERT_TRUE(r.spec);
  ASSERT_FALSE(r.spec->serial.frame_formats.empty());
  EXPECT_EQ(r.spec->serial.frame_formats[0], "8E1");
}

// Issue 37: a fact printed two ways as outcomes (readable or not) gives its
// readings in words and counts as inferred for a case's level; an erratum
// that contests `address` makes the read and write of every register it names
// (here through `area:`) printed two ways; `class:` is kept.
TEST(Loader, ReadingsInWordsAndContestedAddresses) {
  std::ifstream in(fs::path(MBCONFORM_TEST_DIR) / "valid" / "minimal.yaml");
  std::stringstream ss;
  ss << in.rdbuf();
  std::string text = ss.str();
  auto replace = [&](const std::string& from, const std::string& to) {
    auto at = text.find(from);
    ASSERT_NE(at, std::string::npos) << from;
    text.replace(at, from.size(), to);
  };
  replace("registers:\n", R"YAML(registers:
  - address: 0x0040
    name: {en: filter}
    access: rw
    type: u16
    erratum: no-such-input
    section: "2"
    basis:
      read: {either: ["a register (the table)", "no register (the port list)"], erratum: no-such-input}
)YAML");
  replace("errata: []", R"YAML(errata:
  - {id: no-such-input, section: "2", kind: table_vs_text, printed: "t", resolved: "r", why: "w", contests: [read]}
  - {id: offset, section: "2", kind: other, class: nit, printed: "+1", resolved: "r", why: "w", contests: [address], area: {from: 0x0010, to: 0x001F}}
)YAML");
  auto r = load_spec_text(text, "minimal.yaml");
  std::string all;
  for (const auto& d : r.diagnostics) all += "\n  " + d.str();
  ASSERT_TRUE(r.ok()) << all;
  const auto* filter = r.spec->find_register(0x0040);
  ASSERT_TRUE(filter);
  auto b = filter->basis_of(mbc::spec::Fact::read);
  EXPECT_EQ(b.basis, mbc::spec::Basis::either);
  EXPECT_TRUE(mbc::spec::words_only(b));
  EXPECT_TRUE(mbc::spec::demotes(b));  // its cases are OBSERVED
  EXPECT_FALSE(mbc::spec::demotes(filter->basis_of(mbc::spec::Fact::write)));
  for (uint16_t a = 0x0010; a < 0x0014; ++a) {
    const auto* seg = r.spec->find_register(a);
    ASSERT_TRUE(seg);
    EXPECT_NE(std::find(seg->errata.begin(), seg->errata.end(), "offset"), seg->errata.end());
    // Every write lands elsewhere one above; a read answers there too, except
    // at the first address of the run (nothing of the area sits below it).
    auto wb = seg->basis_of(mbc::spec::Fact::write);
    EXPECT_EQ(wb.basis, mbc::spec::Basis::either);
    EXPECT_TRUE(mbc::spec::words_only(wb));
    EXPECT_EQ(wb.erratum, "offset");
    EXPECT_EQ(mbc::spec::words_only(seg->basis_of(mbc::spec::Fact::read)), a == 0x0010) << a;
  }
  EXPECT_EQ(r.spec->find_register(0x0000)->basis_of(mbc::spec::Fact::read).basis, mbc::spec::Basis::stated);  // outside the area
  EXPECT_EQ(mbc::spec::erratum_extra(*r.spec, "offset").cls, "nit");
  EXPECT_EQ(mbc::spec::erratum_extra(*r.spec, "offset").area, std::pair(uint16_t(0x0010), uint16_t(0x001F)));
  EXPECT_EQ(mbc::spec::erratum_extra(*r.spec, "no-such-input").cls, "contradiction");
}
