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
      .motion = MotionFacts{
          .section = "6.1; 7.1; 7.6",
          // §6.1 0x0011: microstep 8 = 1000 Pu/rev (the default); speeds are r/min.
          .assumes = {{"microstep", 8, 0, "6.1 (0x0011 = 8: 1000 Pu/rev)"}},
          // §6.1 0x0020-0x0023: start 5 r/min, 100 ms ramps, 60 r/min = 1000 pulses/s.
          .setup = {{"start_speed", 5, 0, "6.1 0x0020"},
                    {"accel_time", 100, 0, "6.1 0x0021"},
                    {"decel_time", 100, 0, "6.1 0x0022"},
                    {"max_speed", 60, 0, "6.1 0x0023"}},
          // §7.1 / §7.6.1: 0x0024 signed pulse count, 0x0027 = 1 a relative position move.
          .distance_key = "total_pulses",
          .signed_distance = true,
          .start_forward = CommandFact{"start_command", 1, 0, "7.6.1"},
          .start_reverse = CommandFact{"start_command", 1, 0, "7.6.1"},
          .position_key = "current_position",
          .max_speed_pulses_per_s = 60.0 / 60.0 * 1000,
          .decel_seconds = 0.100,  // 0x0022: max speed to start speed, then stop (§7.6.2 注意)
          // §7.6.2 0x0028: 0 decelerates, 1 stops at once.
          .stop = CommandFact{"stop_command", 0, 0, "7.6.2"},
          .emergency_stop = CommandFact{"stop_command", 1, 0, "7.6.2"},
          // §6.1 0x0007: bit 0 in position, bit 2 running.
          .status_key = "motion_status",
          .running_mask = 1u << 2,
          .in_position_mask = 1u << 0,
      },
  };

  // HSC60, manual 001. 四 寄存器地址定义 (90) "写入1保存" / (91) "写入1启动清除";
  // both read 1 while in progress and 0 once complete: 100 ms is a bound, not a figure.
  t["hsc60"] = DeviceFacts{
      .device_id = "hsc60",
      .save = CommandFact{"save", 1, 100'000, "四 寄存器地址定义 (90)"},
      .factory_reset = CommandFact{"factory_reset", 1, 100'000, "四 寄存器地址定义 (91)"},
      .motion = MotionFacts{
          .section = "四 寄存器地址定义 (62-75)",
          // 62/64/66 in pulse/s^2 and pulse/s; 72 = 0 incremental.
          .setup = {{"move_mode", 0, 0, "(72) 增量模式"},
                    {"speed", 1600, 0, "(64) 速度"},
                    {"accel", 3200, 0, "(66) 加速度"},
                    {"decel", 3200, 0, "(62) 减加速度"}},
          // (68) travel, then (70) = 1 forward / 2 reverse fixed-length move.
          .distance_key = "travel",
          .start_forward = CommandFact{"motion_command", 1, 0, "(70) 正向定长运动"},
          .start_reverse = CommandFact{"motion_command", 2, 0, "(70) 反向定长运动"},
          // (39)/(40): the pulse count, low and high word.
          .position_key = "pulse_count_low",
          .position_high_key = "pulse_count_high",
          .max_speed_pulses_per_s = 1600,
          .decel_seconds = 1600.0 / 3200.0,
          .stop = CommandFact{"motion_command", 0, 0, "(70) 减速停止"},
          .emergency_stop = CommandFact{"motion_command", 5, 0, "(70) 立即停止"},
          // (75) bit 7 运动完成: 1 once every pulse is sent.
          .status_key = "status",
          .running_mask = 1u << 7,
          .running_when_set = false,
      },
  };

  // Hanstar 7TRSM5740Q, manual 002. §6.2 表 14: 4002 "参数存储到内部 flash"; the
  // value to write is not printed (any write is read as the command). No
  // factory reset is documented.
  t["hanstar-7trsm5740q"] = DeviceFacts{
      .device_id = "hanstar-7trsm5740q",
      .save = CommandFact{"save_command", 1, 10'000, "6.2 表 14 (4002)"},
      .motion = MotionFacts{
          .section = "5.2; 5.3; 5.7; 6.2",
          // §5.7: a pulse period in us is a speed of 1e6/period steps/s; 3008 the start
          // (homing) period, 3009 the running period, 3007 the ramp steps. The manual
          // prints no defaults (§5.6: the master sets them).
          .setup = {{"homing_period", 2000, 0, "6.2 表 14 (3008)"},
                    {"run_period", 500, 0, "6.2 表 14 (3009)"},
                    {"accel_steps", 100, 0, "6.2 表 14 (3007)"},
                    // 3009 is the speed "找零之后" (after homing); 表 16 2008 sets the speed
                    // the next move uses (§5.2).
                    {"speed_period_command", 500, 0, "6.2 表 16 (2008)"}},
          // 表 15: 2004 forward / 2006 reverse by n steps; the write starts the move
          // and counts as a correct homing (§5.3).
          .distance_key = "forward_command",
          .reverse_distance_key = "reverse_command",
          .position_key = "current_position",
          .max_speed_pulses_per_s = 1e6 / 500,
          // §5.7 加速时间 = (start period + run period) * AccSteps * 0.5 us.
          .decel_seconds = (2000 + 500) * 100 * 0.5e-6,
          .stop = CommandFact{"stop_command", 0, 0, "6.3.2 (减速停止)"},
          // 表 M01 bits 2:0: non-zero while running.
          .status_key = "motor_status",
          .running_mask = 0x7,
          // §5.2: "步进一体机不响应定位指令" before a correct homing (2002).
          .positioning_needs_homing = true,
          .position_command_key = "position_command",
      },
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
