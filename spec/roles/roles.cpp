#include "roles/roles.h"

#include <algorithm>
#include <array>
#include <cctype>
#include <string>

namespace mbc::spec {
namespace {

struct Word {
  Role role;
  std::string_view text;
  bool whole_word;  // English: matched only at word boundaries ("run" not in "current")
};

// In order: the first match wins (roles.h). Chinese words match as
// substrings; English ones as words (at word boundaries), case-insensitively,
// in either name. A word that holds another role's word comes before it:
// "停止位" (stop bits) is a frame format before "停止" (stop) is motion,
// "恢复出厂设置" a factory reset before "设置" anything, "save command" a
// save before "command" is motion.
constexpr std::array kLexicon{
    // slave address
    Word{Role::slave_address, "站号", false}, Word{Role::slave_address, "从站地址", false},
    Word{Role::slave_address, "从机地址", false}, Word{Role::slave_address, "通讯地址", false},
    Word{Role::slave_address, "通信地址", false}, Word{Role::slave_address, "设备地址", false},
    Word{Role::slave_address, "本机地址", false}, Word{Role::slave_address, "站地址", false},
    Word{Role::slave_address, "485地址", false}, Word{Role::slave_address, "slave address", true},
    Word{Role::slave_address, "slave id", true}, Word{Role::slave_address, "station address", true},
    Word{Role::slave_address, "station number", true}, Word{Role::slave_address, "station id", true},
    Word{Role::slave_address, "node address", true}, Word{Role::slave_address, "node id", true},
    Word{Role::slave_address, "device address", true}, Word{Role::slave_address, "device id", true},
    Word{Role::slave_address, "modbus address", true}, Word{Role::slave_address, "modbus id", true},
    Word{Role::slave_address, "unit id", true}, Word{Role::slave_address, "communication address", true},
    Word{Role::slave_address, "comm address", true}, Word{Role::slave_address, "rs485 address", true},
    // baud
    Word{Role::baud, "波特率", false}, Word{Role::baud, "通讯速率", false}, Word{Role::baud, "通信速率", false},
    Word{Role::baud, "baud", true}, Word{Role::baud, "baudrate", true}, Word{Role::baud, "baud rate", true},
    Word{Role::baud, "bit rate", true}, Word{Role::baud, "bitrate", true},
    // frame format: data bits and stop bits (before motion's "停止" and "stop")
    Word{Role::frame_format, "数据格式", false}, Word{Role::frame_format, "通讯格式", false},
    Word{Role::frame_format, "通信格式", false}, Word{Role::frame_format, "数据位", false},
    Word{Role::frame_format, "停止位", false}, Word{Role::frame_format, "data format", true},
    Word{Role::frame_format, "frame format", true}, Word{Role::frame_format, "serial format", true},
    Word{Role::frame_format, "stop bits", true}, Word{Role::frame_format, "stop bit", true},
    Word{Role::frame_format, "data bits", true}, Word{Role::frame_format, "data bit", true},
    // parity
    Word{Role::parity, "校验", false}, Word{Role::parity, "奇偶", false}, Word{Role::parity, "parity", true},
    // factory reset (before save: "恢复出厂设置" is not a save)
    Word{Role::factory_reset, "恢复出厂", false}, Word{Role::factory_reset, "出厂设置", false},
    Word{Role::factory_reset, "恢复默认", false}, Word{Role::factory_reset, "恢复缺省", false},
    Word{Role::factory_reset, "参数复位", false}, Word{Role::factory_reset, "初始化", false},
    Word{Role::factory_reset, "factory", true}, Word{Role::factory_reset, "defaults", true},
    Word{Role::factory_reset, "default settings", true}, Word{Role::factory_reset, "restore default", true},
    Word{Role::factory_reset, "load default", true}, Word{Role::factory_reset, "reset to default", true},
    Word{Role::factory_reset, "initialise", true}, Word{Role::factory_reset, "initialize", true},
    // save
    Word{Role::save, "保存", false}, Word{Role::save, "存储", false}, Word{Role::save, "储存", false},
    Word{Role::save, "固化", false}, Word{Role::save, "eeprom", true}, Word{Role::save, "store", true},
    Word{Role::save, "save", true}, Word{Role::save, "flash", true},
    // motion: a write can start, stop, reverse or restart the drive
    Word{Role::motion, "运行", false}, Word{Role::motion, "启动", false}, Word{Role::motion, "启停", false},
    Word{Role::motion, "停止", false}, Word{Role::motion, "停机", false}, Word{Role::motion, "急停", false},
    Word{Role::motion, "正转", false}, Word{Role::motion, "反转", false}, Word{Role::motion, "方向", false},
    Word{Role::motion, "点动", false}, Word{Role::motion, "寸动", false}, Word{Role::motion, "控制字", false},
    Word{Role::motion, "命令", false}, Word{Role::motion, "指令", false}, Word{Role::motion, "回零", false},
    Word{Role::motion, "回原点", false}, Word{Role::motion, "原点回归", false}, Word{Role::motion, "故障复位", false},
    Word{Role::motion, "run", true}, Word{Role::motion, "start", true}, Word{Role::motion, "stop", true},
    Word{Role::motion, "jog", true}, Word{Role::motion, "direction", true}, Word{Role::motion, "control word", true},
    Word{Role::motion, "controlword", true}, Word{Role::motion, "command", true}, Word{Role::motion, "forward", true},
    Word{Role::motion, "reverse", true}, Word{Role::motion, "homing", true}, Word{Role::motion, "home", true},
    Word{Role::motion, "move", true}, Word{Role::motion, "reversing", true}, Word{Role::motion, "fault reset", true},
    Word{Role::motion, "reset fault", true},
};

std::string lower(std::string_view s) {
  std::string out(s);
  std::transform(out.begin(), out.end(), out.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return out;
}

bool word_char(char c) { return std::isalnum(static_cast<unsigned char>(c)) != 0; }

bool contains(const std::string& hay, std::string_view needle, bool whole_word) {
  for (size_t at = hay.find(needle); at != std::string::npos; at = hay.find(needle, at + 1)) {
    if (!whole_word) return true;
    bool left = at == 0 || !word_char(hay[at - 1]);
    size_t end = at + needle.size();
    bool right = end >= hay.size() || !word_char(hay[end]);
    if (left && right) return true;
  }
  return false;
}

}  // namespace

const char* to_string(Role r) {
  switch (r) {
    case Role::none: return "none";
    case Role::slave_address: return "slave-address";
    case Role::baud: return "baud";
    case Role::parity: return "parity";
    case Role::frame_format: return "frame-format";
    case Role::motion: return "motion";
    case Role::save: return "save";
    case Role::factory_reset: return "factory-reset";
  }
  return "none";
}

std::optional<Role> role_from_string(std::string_view text) {
  std::string t = lower(text);
  std::replace(t.begin(), t.end(), '_', '-');
  std::replace(t.begin(), t.end(), ' ', '-');
  for (Role r : {Role::none, Role::slave_address, Role::baud, Role::parity, Role::frame_format, Role::motion, Role::save,
                 Role::factory_reset})
    if (t == to_string(r)) return r;
  return std::nullopt;
}

std::vector<RoleWord> role_lexicon() {
  std::vector<RoleWord> out;
  for (const Word& w : kLexicon) out.push_back({w.role, w.text});
  return out;
}

RoleMatch role_of_name(std::string_view en, std::string_view zh) {
  // '_' and '-' read as spaces: "baud_rate", "slave-id" (template ids).
  auto words = [](std::string_view s) {
    std::string t = lower(s);
    std::replace(t.begin(), t.end(), '_', ' ');
    std::replace(t.begin(), t.end(), '-', ' ');
    return t;
  };
  const std::string e = words(en), z = words(zh);
  for (const Word& w : kLexicon) {
    if (contains(z, w.text, w.whole_word) || contains(e, w.text, w.whole_word)) return {w.role, std::string(w.text)};
  }
  return {};
}

}  // namespace mbc::spec
