#include "properties/facts.h"

#include <map>

namespace mbc::conf::props {

namespace {

// One entry per device; registers by spec key. Times are generous bounds
// where the manual gives none (a read-back is the real check).
std::map<std::string, DeviceFacts> make_table() {
  std::map<std::string, DeviceFacts> t;

  // SIHONG 57HS-R, manual 000. §6.1 0x002B: "1 恢复出厂设置; 2 保存所有 RW 属性的参数到 EEPROM".
  t["sihong-57hs-r"] = DeviceFacts{
      .device_id = "sihong-57hs-r",
      .save = CommandFact{"param_command", 2, 10'000, "6.1 (0x002B = 2)"},
      .factory_reset = CommandFact{"param_command", 1, 10'000, "6.1 (0x002B = 1)"},
  };

  // HSC60, manual 001. 四 寄存器地址定义 (90) "写入1保存" / (91) "写入1启动清除";
  // both read 1 while in progress and 0 once complete: 100 ms is a bound, not a figure.
  t["hsc60"] = DeviceFacts{
      .device_id = "hsc60",
      .save = CommandFact{"save", 1, 100'000, "四 寄存器地址定义 (90)"},
      .factory_reset = CommandFact{"factory_reset", 1, 100'000, "四 寄存器地址定义 (91)"},
  };

  // Hanstar 7TRSM5740Q, manual 002. §6.2 表 14: 4002 "参数存储到内部 flash"; the
  // value to write is not printed (any write is read as the command). No
  // factory reset is documented.
  t["hanstar-7trsm5740q"] = DeviceFacts{
      .device_id = "hanstar-7trsm5740q",
      .save = CommandFact{"save_command", 1, 10'000, "6.2 表 14 (4002)"},
  };

  return t;
}

}  // namespace

const DeviceFacts* facts_for(const std::string& device_id) {
  static const std::map<std::string, DeviceFacts> table = make_table();
  auto it = table.find(device_id);
  return it == table.end() ? nullptr : &it->second;
}

}  // namespace mbc::conf::props
