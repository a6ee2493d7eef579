// The role lexicon (spec/roles/roles.h): names as vendors print them, in
// Chinese and English, and the role a live run must guard each by. The
// expected roles are read from the names here, not from the lexicon's output.
#include <fstream>
#include <sstream>

#include <gtest/gtest.h>

#include "roles/roles.h"

namespace mbc::spec {
namespace {

struct Named {
  const char* name;
  Role role;
};

class RoleOfName : public ::testing::TestWithParam<Named> {};

TEST_P(RoleOfName, GivesTheRoleTheNameSays) {
  EXPECT_EQ(to_string(role_of_name(GetParam().name).role), std::string(to_string(GetParam().role))) << GetParam().name;
}

INSTANTIATE_TEST_SUITE_P(
    Names, RoleOfName,
    ::testing::Values(
        // slave address
        Named{"站号", Role::slave_address}, Named{"从站地址", Role::slave_address}, Named{"本机通讯地址", Role::slave_address},
        Named{"设备地址", Role::slave_address}, Named{"Slave Address", Role::slave_address},
        Named{"Modbus ID", Role::slave_address}, Named{"RS485 address", Role::slave_address},
        Named{"slave_id", Role::slave_address},
        // baud
        Named{"波特率", Role::baud}, Named{"通讯波特率设定", Role::baud}, Named{"Baud Rate", Role::baud},
        Named{"BAUDRATE", Role::baud}, Named{"baud_rate", Role::baud},
        // parity and frame format ("停止位" is stop bits, not a stop)
        Named{"校验位", Role::parity}, Named{"奇偶校验", Role::parity}, Named{"Parity", Role::parity},
        Named{"停止位", Role::frame_format}, Named{"数据位", Role::frame_format}, Named{"通讯数据格式", Role::frame_format},
        Named{"Stop Bits", Role::frame_format}, Named{"stop bit", Role::frame_format}, Named{"Data Format", Role::frame_format},
        // factory reset before save
        Named{"恢复出厂设置", Role::factory_reset}, Named{"参数初始化", Role::factory_reset},
        Named{"Restore Factory Defaults", Role::factory_reset}, Named{"Load default settings", Role::factory_reset},
        // save ("EEPROM" in a Chinese name, any case)
        Named{"保存参数", Role::save}, Named{"保存到EEPROM", Role::save}, Named{"参数固化", Role::save},
        Named{"Save to EEPROM", Role::save}, Named{"Store parameters", Role::save}, Named{"Save command", Role::save},
        // motion
        Named{"运行命令", Role::motion}, Named{"启动", Role::motion}, Named{"正转点动", Role::motion}, Named{"控制字", Role::motion},
        Named{"急停", Role::motion}, Named{"旋转方向", Role::motion}, Named{"Run Command", Role::motion},
        Named{"Drive Start", Role::motion}, Named{"Start-Stop-Reverse", Role::motion}, Named{"Reversing On", Role::motion},
        Named{"Drive Control Word", Role::motion}, Named{"Jog", Role::motion}, Named{"Direction", Role::motion},
        Named{"Command", Role::motion}, Named{"drive_start", Role::motion},
        // none: English words match whole ("current" holds no "run", "restore" no "store")
        Named{"Output Current", Role::none}, Named{"Running Hours", Role::none}, Named{"Frequency Reference (Hz)", Role::none},
        Named{"目标速度", Role::none}, Named{"母线电压", Role::none}, Named{"Restored value", Role::none},
        Named{"Startup torque", Role::none}, Named{"Return", Role::none}, Named{"", Role::none}));

TEST(RoleOfName, NamesTheWordThatMatched) {
  EXPECT_EQ(role_of_name("通讯波特率").word, "波特率");
  EXPECT_EQ(role_of_name("Save to EEPROM").word, "eeprom");  // "eeprom" comes before "save" in the lexicon
  EXPECT_EQ(role_of_name("Output Current").word, "");
  // Either name: the Chinese one as printed, the English one translated.
  EXPECT_EQ(role_of_name("register 7", "波特率").role, Role::baud);
  EXPECT_EQ(role_of_name("baud rate", "").role, Role::baud);
}

TEST(RoleFromString, ReadsARoleColumn) {
  for (Role r : {Role::none, Role::slave_address, Role::baud, Role::parity, Role::frame_format, Role::motion, Role::save,
                 Role::factory_reset})
    EXPECT_EQ(role_from_string(to_string(r)), r) << to_string(r);
  EXPECT_EQ(role_from_string("Slave_Address"), Role::slave_address);
  EXPECT_EQ(role_from_string("factory reset"), Role::factory_reset);
  EXPECT_EQ(role_from_string("NONE"), Role::none);
  EXPECT_EQ(role_from_string("start"), std::nullopt);
  EXPECT_EQ(role_from_string(""), std::nullopt);
}

TEST(RoleLexicon, EveryWordMatchesItsOwnRole) {
  // No earlier word of another role swallows a later one (the order is the rule).
  for (const auto& w : role_lexicon()) EXPECT_EQ(role_of_name(std::string(w.word)).role, w.role) << w.word;
}

TEST(RoleLexicon, TheReadmeListsEveryWord) {
  std::ifstream in(SPEC_README);
  std::stringstream text;
  text << in.rdbuf();
  const std::string readme = text.str();
  size_t at = readme.find("\n## Roles");
  ASSERT_NE(at, std::string::npos) << "spec/README.md has no Roles section";
  std::string section = readme.substr(at, readme.find("\n## ", at + 1) - at);
  for (const auto& w : role_lexicon())
    EXPECT_NE(section.find("`" + std::string(w.word) + "`"), std::string::npos) << w.word << " is not in spec/README.md Roles";
}

}  // namespace
}  // namespace mbc::spec
