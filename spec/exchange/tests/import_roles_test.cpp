// Roles in imported maps (issue 35 item 2): the CSV and wb-mqtt-serial
// importers classify every register by its name (or the sheet's role
// column), write the role in the spec language's own terms, and mark every
// fact as the sheet's claim, not a manual's. The expected roles are read
// from the rows' names by hand, not taken from the importer's output.
#include <fmt/core.h>

#include <fstream>
#include <map>
#include <sstream>

#include <gtest/gtest.h>

#include "csv.h"
#include "exchange.h"
#include "loader.h"

namespace mbc::exchange {
namespace {

using spec::Access;
using spec::Role;

std::string read(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream t;
  t << in.rdbuf();
  return t.str();
}

spec::Spec load(const ImportResult& r, const std::string& id) {
  auto l = spec::load_spec_text(r.yaml, id + ".yaml");
  std::string diags;
  for (const auto& d : l.diagnostics) diags += d.str() + "\n";
  EXPECT_TRUE(l.ok()) << diags << r.yaml;
  return l.spec ? *l.spec : spec::Spec{};
}

std::map<uint32_t, Role> roles_of(const ImportResult& r) {
  std::map<uint32_t, Role> out;
  for (const auto& c : r.classified) out[c.address] = c.role;
  return out;
}

const spec::Register* reg(const spec::Spec& s, uint32_t a) {
  for (const auto& r : s.registers)
    if (r.address == a && r.table == spec::Table::holding) return &r;
  return nullptr;
}

std::map<uint32_t, std::string> settings_of(const spec::Spec& s) {
  std::map<uint32_t, std::string> out;
  for (const auto& st : s.serial.settings) out[st.register_address] = st.setting;
  return out;
}

// Every fact of every register is the sheet's claim: inferred, never stated.
void expect_nothing_stated(const spec::Spec& s) {
  for (const auto& r : s.registers)
    for (auto f : {spec::Fact::read, spec::Fact::write, spec::Fact::range, spec::Fact::default_value, spec::Fact::type,
                   spec::Fact::word_order})
      EXPECT_TRUE(r.basis_of(f).is_inferred()) << r.address << " " << spec::to_string(f);
  for (const auto& fc : s.profile.function_codes) EXPECT_TRUE(fc.basis_of("supported").is_inferred()) << "FC " << fc.code;
}

// vendor-vfd-gbk.csv and vendor-vfd-en.csv: one VFD's sheet, in GBK Chinese and
// in English, 15 rows. Read by hand: 站号/Slave Address, 波特率/Baud Rate,
// 校验位/Parity, 停止位/Stop Bits set the line; 运行命令/Run Command and
// 控制字/Control Word move the drive; 保存到EEPROM/Save to EEPROM saves;
// 恢复出厂设置/Restore Factory Defaults resets; 点动频率/Jog Frequency says
// `none` in its role column and 自定义参数/Custom Parameter `motion`;
// 累计运行时间 holds 运行 (run), "Total Running Time" holds no whole word.
const std::map<uint32_t, Role> kVfdRoles = {
    {0x1000, Role::slave_address}, {0x1001, Role::baud}, {0x1002, Role::parity}, {0x1003, Role::frame_format},
    {0x2000, Role::motion},        {0x2001, Role::motion}, {0x2002, Role::none}, {0x2003, Role::none},
    {0x3000, Role::none},          {0x3003, Role::none},   {0x4000, Role::save}, {0x4001, Role::factory_reset},
    {0x4002, Role::motion},        {0x5000, Role::none}};

void expect_vfd(const ImportResult& r, const std::string& id, Role running_time) {
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  auto roles = roles_of(r);
  auto want = kVfdRoles;
  want[0x3001] = running_time;
  EXPECT_EQ(roles.size(), want.size());
  for (const auto& [a, role] : want) EXPECT_EQ(spec::to_string(roles[a]), std::string(spec::to_string(role))) << fmt::format("0x{:04X}", a);
  for (const auto& c : r.classified)
    if (c.address == 0x2003 || c.address == 0x4002) {
      EXPECT_EQ(c.word, "role column");
    }

  spec::Spec s = load(r, id);
  // Line settings: serial.settings, the register left as the sheet says (rw).
  EXPECT_EQ(settings_of(s), (std::map<uint32_t, std::string>{
                                {0x1000, "slave_id"}, {0x1001, "baud_rate"}, {0x1002, "frame_format"}, {0x1003, "frame_format"}}));
  EXPECT_EQ(reg(s, 0x1001)->access, Access::rw);
  // Motion: a command that moves.
  for (uint32_t a : {0x2000u, 0x2001u, 0x4002u}) {
    ASSERT_TRUE(reg(s, a)->command) << a;
    EXPECT_EQ(reg(s, a)->access, Access::command) << a;
    EXPECT_TRUE(reg(s, a)->command->motion) << a;
    EXPECT_FALSE(reg(s, a)->command->eeprom) << a;
  }
  // Save and factory reset: a command that writes the EEPROM.
  for (uint32_t a : {0x4000u, 0x4001u}) {
    ASSERT_TRUE(reg(s, a)->command) << a;
    EXPECT_TRUE(reg(s, a)->command->eeprom) << a;
    EXPECT_FALSE(reg(s, a)->command->motion) << a;
  }
  // The role column's `none` keeps a jog frequency a setting.
  EXPECT_EQ(reg(s, 0x2003)->access, Access::rw);
  EXPECT_EQ(reg(s, 0x2002)->access, Access::rw);
  // A read-only register keeps its access whatever its name.
  EXPECT_EQ(reg(s, 0x3001)->access, Access::ro);
  // 32-bit rows with no type: by the range (0~4000000) and by the byte order alone (CDAB).
  EXPECT_EQ(reg(s, 0x3001)->type, spec::DataType::u32);
  EXPECT_EQ(reg(s, 0x3001)->word_order, spec::WordOrder::low_first);
  EXPECT_EQ(reg(s, 0x3003)->type, spec::DataType::u32);
  EXPECT_EQ(reg(s, 0x3003)->words, 2);
  // BADC: imported as two words with no range, and said.
  EXPECT_EQ(reg(s, 0x5000)->words, 2);
  EXPECT_FALSE(reg(s, 0x5000)->range);
  bool said = false;
  for (const auto& w : r.warnings) said = said || w.find("byte order 'BADC'") != std::string::npos;
  EXPECT_TRUE(said);
  EXPECT_EQ(s.device.manual.source, "csv");
  expect_nothing_stated(s);
}

TEST(ImportRoles, VendorSheetInGbkChinese) {
  expect_vfd(import_csv(read(VENDOR_VFD_GBK_CSV), VENDOR_VFD_GBK_CSV, "vfd-zh"), "vfd-zh", Role::motion);
}

TEST(ImportRoles, VendorSheetInEnglish) {
  expect_vfd(import_csv(read(VENDOR_VFD_EN_CSV), VENDOR_VFD_EN_CSV, "vfd-en"), "vfd-en", Role::none);
}

TEST(ImportRoles, TheTableNamesEveryRoleAndItsWord) {
  auto r = import_csv(read(VENDOR_VFD_EN_CSV), VENDOR_VFD_EN_CSV, "vfd-en");
  std::string t = classification_table(r);
  for (const char* line : {"holding register 0x1001", "baud", "serial.settings", "'baud'", "command, motion", "'run'",
                           "command, eeprom", "'factory'", "role column"})
    EXPECT_NE(t.find(line), std::string::npos) << line << "\n" << t;
  EXPECT_NE(t.find("9 of 15 registers have a role (2 from the role column); 6 have none"), std::string::npos) << t;
}

// The sheets committed before roles: their rows' names, read by hand.
TEST(ImportRoles, ExampleCsv) {
  auto r = import_csv(read(EXAMPLE_CSV), EXAMPLE_CSV, "acme-x1");
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  // Target speed (its note says "start command": a note is not a name),
  // Acceleration time, Microstep, Position, Status, Enable: none. "Save parameters": save.
  for (const auto& c : r.classified)
    EXPECT_EQ(c.role, c.name == "Save parameters" ? Role::save : Role::none) << c.name;
  spec::Spec s = load(r, "acme-x1");
  EXPECT_TRUE(reg(s, 0x0090)->command->eeprom);
  EXPECT_TRUE(s.serial.settings.empty());
  expect_nothing_stated(s);
}

TEST(ImportRoles, VendorGbkCsv) {
  auto r = import_csv(read(VENDOR_GBK_CSV), VENDOR_GBK_CSV, "vendor");
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  // 目标速度, 加速时间, 预留, 目标位置, 母线电压: none; 保存参数: save.
  for (const auto& c : r.classified) EXPECT_EQ(c.role, c.name == "保存参数" ? Role::save : Role::none) << c.name;
  spec::Spec s = load(r, "vendor");
  EXPECT_TRUE(reg(s, 0x0013)->command->eeprom);
  expect_nothing_stated(s);
}

TEST(ImportRoles, ABadRoleColumnIsAnErrorWithItsLine) {
  auto r = import_csv("address,name,access,role\n0x10,Speed,rw,start\n", "r.csv", "r");
  ASSERT_EQ(r.errors.size(), 1u);
  EXPECT_NE(r.errors[0].find("r.csv:2: error: role 'start' is not none, slave-address"), std::string::npos) << r.errors[0];
}

TEST(Import32Bit, RecognisedWithoutATypeColumn) {
  auto r = import_csv(
      "address,name,access,range,byte order\n"
      "0x10,Position,rw,-100000~100000,CDAB\n"  // negative and beyond 16 bits: s32
      "0x12,Counter,ro,,ABCD\n"                 // a 4-byte order alone: u32
      "0x14,Offset,rw,-10~10,\n"                // negative, 16 bits: s16
      "0x15,Total,ro,0~100000,\n",              // beyond 16 bits with no order: an error naming the word order
      "w.csv", "w");
  ASSERT_EQ(r.errors.size(), 1u) << r.yaml;
  EXPECT_NE(r.errors[0].find("w.csv:5: error: a 2-word register needs a word order"), std::string::npos) << r.errors[0];
  r = import_csv("address,name,access,range,byte order\n0x10,Position,rw,-100000~100000,CDAB\n0x12,Counter,ro,,ABCD\n"
                 "0x14,Offset,rw,-10~10,\n",
                 "w.csv", "w");
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  spec::Spec s = load(r, "w");
  EXPECT_EQ(reg(s, 0x10)->type, spec::DataType::s32);
  EXPECT_EQ(reg(s, 0x10)->word_order, spec::WordOrder::low_first);
  EXPECT_EQ(reg(s, 0x12)->type, spec::DataType::u32);
  EXPECT_EQ(reg(s, 0x12)->word_order, spec::WordOrder::high_first);
  EXPECT_EQ(reg(s, 0x14)->type, spec::DataType::s16);
}

TEST(Import32Bit, AnIntOfA32BitRangeIs32BitAndSaid) {
  auto r = import_csv("address,name,access,type,range,word order\n0x10,Count,rw,int,0~100000,ABCD\n", "i.csv", "i");
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  EXPECT_EQ(reg(load(r, "i"), 0x10)->type, spec::DataType::s32);  // int is signed
  ASSERT_EQ(r.warnings.size(), 1u);
  EXPECT_NE(r.warnings[0].find("type 'int' with range 0..100000: read as s32"), std::string::npos) << r.warnings[0];
  // An explicit 16-bit type with a 32-bit range stays an error: the sheet contradicts itself.
  r = import_csv("address,name,access,type,range\n0x10,Count,rw,uint16,0~100000\n", "i.csv", "i");
  ASSERT_EQ(r.errors.size(), 1u);
}

TEST(Import32Bit, ByteSwappedOrdersImportWithoutValues) {
  auto r = import_csv("address,name,access,type,range,default,byte order\n0x10,A,rw,int32,-5~5,1,DCBA\n0x12,B,rw,u16,0~9,1,BADC\n",
                      "b.csv", "b");
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  spec::Spec s = load(r, "b");
  EXPECT_EQ(reg(s, 0x10)->words, 2);
  EXPECT_EQ(reg(s, 0x10)->word_order, spec::WordOrder::low_first);  // DCBA: the low word first, its bytes swapped
  EXPECT_FALSE(reg(s, 0x10)->range);
  EXPECT_FALSE(reg(s, 0x10)->default_value);
  EXPECT_EQ(reg(s, 0x12)->words, 1);
  EXPECT_FALSE(reg(s, 0x12)->range);
  EXPECT_EQ(r.warnings.size(), 2u);
}

// CSV formula injection: a cell a spreadsheet would run is written as text
// and read back as it was.
TEST(CsvFormula, EscapedOnExportAndReadBack) {
  EXPECT_EQ(csv_field("=1+2"), "\"'=1+2\"");
  EXPECT_EQ(csv_field("@SUM(A1)"), "\"'@SUM(A1)\"");
  EXPECT_EQ(csv_field("+cmd|' /C calc'!A0"), "\"'+cmd|' /C calc'!A0\"");
  EXPECT_EQ(csv_field("-2+3"), "\"'-2+3\"");
  EXPECT_EQ(csv_field("'=x"), "\"''=x\"");  // an apostrophe the user wrote survives the round trip
  EXPECT_EQ(csv_field("-10"), "-10");       // a number stays a number
  EXPECT_EQ(csv_field("-0.5"), "-0.5");
  EXPECT_EQ(csv_field("speed"), "speed");
  EXPECT_EQ(csv_text("'=1+2"), "=1+2");
  EXPECT_EQ(csv_text("''=x"), "'=x");
  EXPECT_EQ(csv_text("'quoted'"), "'quoted'");
}

TEST(CsvFormula, RoundTripThroughExportAndImport) {
  const std::vector<std::string> names = {"=HYPERLINK(\"http://x\",\"y\")", "+1+1", "-2+3", "@SUM(A1:A2)", "it's =fine", "plain"};
  std::string sheet = "address,name,access,unit,description\n";
  for (size_t i = 0; i < names.size(); ++i) {
    std::string quoted = "\"";
    for (char c : names[i]) quoted += c == '"' ? std::string("\"\"") : std::string(1, c);
    sheet += fmt::format("0x{:04X},{}\",ro,=A1,@note\n", 0x100 + i, quoted);
  }
  auto first = import_csv(sheet, "f.csv", "f");
  ASSERT_TRUE(first.errors.empty()) << first.errors[0];
  spec::Spec s = load(first, "f");
  std::string out = export_csv(s);
  for (const auto& rec : parse_csv(out))
    for (const auto& cell : rec.fields)
      EXPECT_TRUE(cell.empty() || std::string("=+@").find(cell[0]) == std::string::npos ||
                  cell.find_first_not_of("0123456789.-e") == std::string::npos)
          << "a formula cell: " << cell;
  auto back = import_csv(out, "f-out.csv", "f");
  ASSERT_TRUE(back.errors.empty()) << back.errors[0];
  spec::Spec b = load(back, "f");
  ASSERT_EQ(b.registers.size(), names.size());
  for (size_t i = 0; i < names.size(); ++i) {
    EXPECT_EQ(b.registers[i].name.en, names[i]);
    EXPECT_EQ(b.registers[i].unit, "=A1");
    EXPECT_EQ(b.registers[i].note, "@note");
  }
}

// wb-mqtt-serial templates (spec/exchange/tests/wb-mqtt-serial/, with their
// licence): the roles read from the channels' names by hand.
struct Template {
  const char* label;
  const char* file;
  std::map<uint32_t, Role> roles;  // every register not listed has none
};

class WbRoles : public ::testing::TestWithParam<Template> {};

TEST_P(WbRoles, FromTheChannelNames) {
  std::string path = std::string(WB_DIR) + "/" + GetParam().file;
  auto r = import_wb_template(read(path), path, "wb");
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  spec::Spec s = load(r, "wb");
  EXPECT_EQ(s.device.manual.source, "wb-mqtt-serial");
  expect_nothing_stated(s);
  ASSERT_FALSE(r.classified.empty());
  for (const auto& c : r.classified) {
    auto it = GetParam().roles.find(c.address);
    Role want = it == GetParam().roles.end() ? Role::none : it->second;
    EXPECT_EQ(spec::to_string(c.role), std::string(spec::to_string(want))) << c.address << " " << c.name;
    const spec::Register* g = reg(s, c.address);
    ASSERT_TRUE(g);
    EXPECT_EQ(g->access == Access::command && g->command && g->command->motion, want == Role::motion) << c.address;
  }
}

INSTANTIATE_TEST_SUITE_P(
    Templates, WbRoles,
    ::testing::Values(
        // Danfoss FC 51: the control word 49999 ("Drive Control Word", its bits
        // "Drive Start", "Reversing On", "Reset Fault") moves the drive; the
        // status word's "Drive Running" is read-only and "running" is not "run".
        Template{"danfoss", "config-danfoss-fc51.json", {{49999, Role::motion}}},
        // MST-24: "Command" (18) and "Direction" (23).
        Template{"mst24", "config-mst-24.json", {{18, Role::motion}, {23, Role::motion}}},
        // T13: "Start-Stop-Reverse" (3).
        Template{"t13", "config-t13-frequency-v2.json", {{3, Role::motion}}}),
    [](const auto& info) { return std::string(info.param.label); });

TEST(WbRoles, LineSettingsAndSavesOfATemplate) {
  const std::string t = R"({"device": {"id": "x", "channels": [
      {"name": "Baud rate", "address": 110, "reg_type": "holding"},
      {"name": "Slave ID", "address": 128, "reg_type": "holding"},
      {"name": "Save settings", "address": 200, "reg_type": "holding"},
      {"name": "Factory reset", "address": 201, "reg_type": "holding"},
      {"name": "Temperature", "address": 1, "reg_type": "input"}]}})";
  auto r = import_wb_template(t, "x.json", "x");
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  spec::Spec s = load(r, "x");
  EXPECT_EQ(settings_of(s), (std::map<uint32_t, std::string>{{110, "baud_rate"}, {128, "slave_id"}}));
  EXPECT_TRUE(reg(s, 200)->command->eeprom);
  EXPECT_TRUE(reg(s, 201)->command->eeprom);
  EXPECT_FALSE(reg(s, 201)->command->motion);
}

}  // namespace
}  // namespace mbc::exchange
