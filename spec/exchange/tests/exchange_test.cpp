// CSV import and export (spec/exchange/exchange.h): every device's map goes
// out as CSV and comes back the same; bad rows are errors with their line;
// the README's example imports into a spec that passes `spec check`.
#include <fmt/core.h>

#include <fstream>
#include <sstream>

#include <gtest/gtest.h>

#include "exchange.h"
#include "loader.h"

namespace mbc::exchange {
namespace {

using spec::DataType;

spec::Spec load(const ImportResult& r, const std::string& id) {
  auto l = spec::load_spec_text(r.yaml, id + ".yaml");
  std::string diags;
  for (const auto& d : l.diagnostics) diags += d.str() + "\n";
  EXPECT_TRUE(l.ok()) << diags << r.yaml;
  return l.spec ? *l.spec : spec::Spec{};
}

DataType wire_type(const spec::Register& r) {
  if (r.type == DataType::enumeration || r.type == DataType::bitfield) return r.words == 2 ? DataType::u32 : DataType::u16;
  return r.type;
}

class RoundTrip : public ::testing::TestWithParam<std::string> {};

TEST_P(RoundTrip, CsvExportThenImportGivesTheSameMap) {
  spec::Spec s = spec::load_spec_by_id(GetParam());
  std::string csv = export_csv(s);
  auto r = import_csv(csv, GetParam() + ".csv", "round-trip");
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  spec::Spec back = load(r, "round-trip");
  ASSERT_EQ(back.registers.size(), s.registers.size());
  for (size_t i = 0; i < s.registers.size(); ++i) {
    const auto& a = s.registers[i];
    const auto& b = back.registers[i];
    SCOPED_TRACE(std::string(spec::to_string(a.table)) + " " + std::to_string(a.address));
    EXPECT_EQ(b.table, a.table);
    EXPECT_EQ(b.address, a.address);
    EXPECT_EQ(b.words, a.words);
    EXPECT_EQ(b.type, wire_type(a));  // enum and bitfield travel as their integer type
    EXPECT_EQ(b.word_order, a.word_order);
    EXPECT_EQ(b.range.has_value(), a.range.has_value());
    if (a.range && b.range) {
      EXPECT_EQ(b.range->min, a.range->min);
      EXPECT_EQ(b.range->max, a.range->max);
    }
    EXPECT_EQ(b.default_value, a.default_value);
    EXPECT_EQ(b.unit, a.unit);
    EXPECT_EQ(b.scale, a.scale);
    EXPECT_EQ(b.access, a.access);
    EXPECT_EQ(b.name.en, a.name.en);
    // Every imported fact cites the CSV row it came from (row 1 is the
    // header), and is the sheet's claim, not a manual's (inferred).
    EXPECT_EQ(b.section, GetParam() + ".csv:" + std::to_string(i + 2));
    for (auto f : {spec::Fact::read, spec::Fact::write, spec::Fact::range, spec::Fact::default_value, spec::Fact::type})
      EXPECT_EQ(b.basis_of(f).basis, spec::Basis::inferred) << spec::to_string(f);
    EXPECT_NE(b.basis_of(spec::Fact::write).why.find("not a manual"), std::string::npos);
  }
  EXPECT_EQ(back.device.manual.file, GetParam() + ".csv");
  EXPECT_EQ(back.device.manual.source, "csv");
}

INSTANTIATE_TEST_SUITE_P(Specs, RoundTrip, ::testing::ValuesIn(spec::spec_ids()), [](const auto& info) {
  std::string n = info.param;
  for (char& c : n)
    if (c == '-') c = '_';
  return n;
});

TEST(Import, ReadmeExample) {
  std::ifstream in(EXAMPLE_CSV);
  std::stringstream text;
  text << in.rdbuf();
  auto r = import_csv(text.str(), EXAMPLE_CSV, "acme-x1");
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  spec::Spec s = load(r, "acme-x1");
  ASSERT_EQ(s.registers.size(), 7u);
  // 40001 is holding register 0; 30011 input register 10; 00001 coil 0.
  const auto* speed = s.find_register(0x0000);
  ASSERT_TRUE(speed);
  EXPECT_EQ(speed->name.en, "Target speed");
  EXPECT_EQ(speed->access, spec::Access::rw);
  EXPECT_EQ(speed->range->max, 3000);
  EXPECT_EQ(*speed->default_value, 600);
  EXPECT_EQ(speed->unit, "rpm");
  EXPECT_EQ(speed->section, "example.csv:2");
  const auto* pos = s.find_register(0x000A, spec::Table::input);
  ASSERT_TRUE(pos);
  EXPECT_EQ(pos->type, DataType::s32);
  EXPECT_EQ(pos->word_order, spec::WordOrder::low_first);
  EXPECT_EQ(pos->access, spec::Access::ro);
  EXPECT_EQ(pos->scale, 0.01);
  EXPECT_TRUE(s.find_register(0x0000, spec::Table::coil));
  const auto* save = s.find_register(0x0090);
  ASSERT_TRUE(save);
  EXPECT_EQ(save->access, spec::Access::command);
  ASSERT_TRUE(save->command);
}

struct BadRow {
  const char* csv;
  const char* error;  // the expected first error, after "bad.csv:"
};

class Import : public ::testing::TestWithParam<BadRow> {};

TEST_P(Import, BadRowIsAnErrorWithItsLineAndNothingElse) {
  auto r = import_csv(GetParam().csv, "dir/bad.csv", "bad");
  ASSERT_FALSE(r.errors.empty());
  EXPECT_EQ(r.errors[0], std::string("dir/bad.csv:") + GetParam().error);
  EXPECT_TRUE(r.yaml.empty());
}

INSTANTIATE_TEST_SUITE_P(
    Rows, Import,
    ::testing::Values(
        BadRow{"address,name,access\n0x10,Speed,rw\n0x10,Again,rw\n", "3: error: holding register 0x0010 is also on line 2"},
        BadRow{"address,name,access,type\n5,Speed,rw,u32\n", "2: error: a 2-word register needs a word order (high_first: the "
                                                             "high word at the lower address, or low_first)"},
        BadRow{"address,name,access\n\n\n70000,Speed,rw\n",
               "4: error: address '70000' is not 0..65535 (decimal or 0x...) or a 0x/1x/3x/4x reference"},
        BadRow{"address,name,access,min,max\n1,Speed,rw,10,5\n", "2: error: min 10 is above max 5"},
        BadRow{"address,name,access,min,max,default\n1,Speed,rw,0,100,101\n", "2: error: default 101 is outside 0..100"},
        BadRow{"table,address,name,access\ninput register,1,Speed,rw\n", "2: error: access 'rw': an input register is read-only"},
        BadRow{"table,address,name\ncoil,40001,Run\n", "2: error: address 40001 is a holding register reference but the table column says coil"},
        BadRow{"address,name,access,type\n1,Mode,rw,enum\n",
               "2: error: type 'enum': the CSV carries no value list; write the integer type (u16) and describe the "
               "values, then declare the enum in the spec"},
        BadRow{"address,name,access,byte order\n1,Speed,rw,XYZW\n",
               "2: error: word order 'XYZW' is not high_first or low_first (ABCD, CDAB)"},
        BadRow{"address,name,access,range\n1,Speed,rw,fast\n", "2: error: range 'fast' is not MIN~MAX (0~3000, -10~10, 0..3000)"},
        BadRow{"address,name,access\n1,Speed,\xFF\xFF\n",
               "2: error: the file is neither UTF-8 nor GB18030/GBK (byte 0xFF); save it as CSV UTF-8"},
        BadRow{"address,name,access\n1,\"Speed,rw\n", "2: error: a quoted field is not closed"},
        BadRow{"address,name,access\n1,Speed,rw,extra\n", "2: error: 4 fields, the header has 3"},
        BadRow{"address,name\n1,Speed\n", "2: error: no access for a holding register (ro, rw, wo or command)"}));

TEST(Import, HeaderAliasesAndReferences) {
  auto r = import_csv(
      "Register Type;Reg;Tag;R/W;Data Type;Word Swap;Units;Multiplier\n"
      "Holding Registers;400010;Setpoint;R/W;float;CDAB;bar;0.5\n"
      "Discrete Inputs;10003;Alarm;;;;;\n",
      "semi.csv", "semi");
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  spec::Spec s = load(r, "semi");
  const auto* sp = s.find_register(9);
  ASSERT_TRUE(sp);
  EXPECT_EQ(sp->type, DataType::f32);
  EXPECT_EQ(sp->word_order, spec::WordOrder::low_first);
  EXPECT_EQ(sp->scale, 0.5);
  EXPECT_EQ(sp->unit, "bar");
  const auto* alarm = s.find_register(2, spec::Table::discrete_input);
  ASSERT_TRUE(alarm);
  EXPECT_EQ(alarm->type, DataType::bit);
  EXPECT_EQ(alarm->access, spec::Access::ro);
}

// An unknown column (序号, No., a vendor's own) is said once and ignored.
TEST(Import, UnknownColumnsAreWarnedAndIgnored) {
  auto r = import_csv("No.,address,name,access,colour\n1,1,Speed,rw,red\n", "dir/extra.csv", "extra");
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  ASSERT_EQ(r.warnings.size(), 2u);
  EXPECT_EQ(r.warnings[0].rfind("dir/extra.csv:1: warning: column 'No.' is not one of", 0), 0u) << r.warnings[0];
  EXPECT_NE(r.warnings[1].find("'colour'"), std::string::npos) << r.warnings[1];
  EXPECT_NE(load(r, "extra").find_register(1), nullptr);
}

// A vendor sheet as Chinese Excel saves it: GBK, CRLF, Chinese headers, a
// 序号 column, ranges written a~b (and with a full-width ～), an address
// range for a reserved block, ABCD/CDAB byte orders, 只读/读写/命令.
TEST(Import, AVendorSheetInGbkWithChineseHeaders) {
  std::ifstream in(VENDOR_GBK_CSV, std::ios::binary);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_FALSE(text.empty());
  auto r = import_csv(text, "vendor-gbk.csv", "vendor-gbk");
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  ASSERT_GE(r.warnings.size(), 2u);
  EXPECT_NE(r.warnings[0].find("read as GB18030"), std::string::npos) << r.warnings[0];
  EXPECT_NE(r.warnings[1].find("'序号'"), std::string::npos) << r.warnings[1];
  spec::Spec s = load(r, "vendor-gbk");
  const auto* speed = s.find_register(0);
  ASSERT_TRUE(speed);
  EXPECT_EQ(speed->name.zh, "目标速度");
  EXPECT_EQ(speed->access, spec::Access::rw);
  ASSERT_TRUE(speed->range);
  EXPECT_EQ(speed->range->min, 0);
  EXPECT_EQ(speed->range->max, 3000);
  EXPECT_EQ(speed->unit, "rpm");
  EXPECT_EQ(speed->default_value, 100);
  const auto* accel = s.find_register(1);
  ASSERT_TRUE(accel && accel->range);
  EXPECT_EQ(accel->range->max, 500);  // 1～500, full-width tilde
  for (uint16_t a = 2; a <= 5; ++a) {
    const auto* reserved = s.find_register(a);
    ASSERT_TRUE(reserved) << a;
    EXPECT_EQ(reserved->access, spec::Access::ro);
  }
  const auto* pos = s.find_register(0x10);
  ASSERT_TRUE(pos);
  EXPECT_EQ(pos->type, DataType::s32);
  EXPECT_EQ(pos->word_order, spec::WordOrder::low_first);  // CDAB
  EXPECT_EQ(pos->range->min, -100000);
  const auto* volts = s.find_register(0x12);
  ASSERT_TRUE(volts);
  EXPECT_EQ(volts->scale, 0.1);
  EXPECT_EQ(volts->access, spec::Access::ro);
  const auto* save = s.find_register(0x13);
  ASSERT_TRUE(save);
  EXPECT_EQ(save->access, spec::Access::command);
}

// Spreadsheets of most of Europe: ';' between fields, ',' before decimals.
TEST(Import, DecimalCommas) {
  auto r = import_csv("address;name;access;scale;range\n1;Speed;rw;0,1;0,5~99,5\n", "eu.csv", "eu");
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  const spec::Spec s = load(r, "eu");
  const auto* reg = s.find_register(1);
  ASSERT_TRUE(reg && reg->range);
  EXPECT_EQ(reg->scale, 0.1);
  EXPECT_EQ(reg->range->min, 0.5);
  EXPECT_EQ(reg->range->max, 99.5);
}

// A bad file of 100,000 rows: 20 errors, then how many more.
TEST(Import, AtMostTwentyErrorsThenACount) {
  std::string csv = "address,name,access\n";
  for (int i = 0; i < 100000; ++i) csv += fmt::format("{},Speed{},maybe\n", i % 9000, i);  // one error a row: the access
  auto r = import_csv(csv, "big.csv", "big");
  ASSERT_EQ(r.errors.size(), 21u);
  EXPECT_EQ(r.error_count, 100000u);
  EXPECT_EQ(r.errors.back(), "big.csv: 99980 more errors not shown (100000 in all)");
}

}  // namespace
}  // namespace mbc::exchange
