// Deliberately broken reference devices, chosen by name at run time: the
// teeth of the conformance cases, the properties and the fuzzer. A fault is
// never a code edit: it wraps a correct device, either at the bus (frames in,
// frames out: FaultyBus) or inside the device (a Behaviour decorator around
// the device's own behaviour: power-up, writes, the virtual clock).
//
//   ref:hsc60?fault=swapped-words,lost-write     (conformance/targets/ref_target.cpp)
//   mbconform serve --fault wrong-exception-code --device hsc60@1 --tcp 0
//   mbconform serve --list-faults
//
// Each fault is small and breaks one requirement, named in its description.
// The state-machine faults bend the control executor (engine/control.h,
// ControlTweak) of a device whose spec has `control:`; on a device without
// one they change nothing.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "engine/device.h"

namespace mbc::faults {

enum class Fault {
  wrong_exception_code,
  off_by_one_limit,
  refuse_limit,
  swapped_words,
  accept_out_of_range,
  accept_read_only,
  lost_write,
  reply_other_slave,
  accept_bad_crc,
  answer_broadcast,
  ignore_broadcast,
  bad_reply_crc,
  wrong_byte_count,
  read_before_write,
  forget_persistent,
  keep_volatile,
  overshoot,
  overspeed,
  homing_gate_open,
  slow_estop,
  creep,
  silent_unstated_reads,
  refuse_reserved,
  silent_command_reads,
  // The state machine of a `control:` section (engine/control.h), each
  // stated on the model so that it applies to every device that has one.
  undefined_command_accepted,
  status_bit_wrong,
  transition_missing,
  transition_wrong_target,
  edge_as_level,
  stop_ignored,
};

struct FaultInfo {
  Fault fault;
  const char* name;         // as given on the command line: "wrong-exception-code"
  const char* description;  // one line: what the broken device does, and the rule it breaks
};
const std::vector<FaultInfo>& all_faults();
const char* to_string(Fault f);

// A set of faults; empty = the correct device.
class FaultSet {
 public:
  FaultSet() = default;
  FaultSet(std::initializer_list<Fault> fs) {
    for (Fault f : fs) add(f);
  }
  void add(Fault f) { bits_ |= uint64_t(1) << int(f); }
  bool has(Fault f) const { return bits_ & (uint64_t(1) << int(f)); }
  bool empty() const { return bits_ == 0; }
  std::vector<Fault> list() const;
  std::string names() const;  // "a,b"; "" when empty

 private:
  uint64_t bits_ = 0;
};

// "swapped-words,lost-write" -> the set. Throws std::invalid_argument naming
// the unknown fault and the known ones.
FaultSet parse_faults(const std::string& comma_list);

// A bus of reference devices with faults injected. With an empty set every
// call goes straight to the wrapped ref::Bus (the correct devices). Has the
// interface of ref::Bus that transports use.
class FaultyBus {
 public:
  FaultyBus() = default;
  // Rebuilds each device around a faulty behaviour when a device-level fault
  // is in `faults` (keeping its spec, slave id and stored image).
  FaultyBus(ref::Bus bus, FaultSet faults);

  std::optional<Bytes> handle_rtu(std::span<const uint8_t> adu);
  std::optional<Bytes> handle_pdu(uint8_t unit, std::span<const uint8_t> pdu);
  // The same into the caller's storage (ref::Bus::handle_*_into): the reply's
  // length, 0 for none; `reply` holds max_reply_pdu() (+ 3 for RTU) bytes.
  // Without faults nothing is allocated; with faults the reply is made as
  // above and copied.
  size_t handle_rtu_into(std::span<const uint8_t> adu, std::span<uint8_t> reply);
  size_t handle_pdu_into(uint8_t unit, std::span<const uint8_t> pdu, std::span<uint8_t> reply);
  size_t max_reply_pdu() const { return bus_.max_reply_pdu(); }
  ref::Device* find(uint8_t slave_id) { return bus_.find(slave_id); }
  std::vector<std::unique_ptr<ref::Device>>& devices() { return bus_.devices(); }
  void advance(uint64_t dt_us) { bus_.advance(dt_us); }
  const FaultSet& faults() const { return faults_; }

 private:
  // The PDU faults around one device's engine.
  std::optional<Bytes> device_pdu(ref::Device& d, std::span<const uint8_t> pdu, bool broadcast);
  ref::Bus bus_;
  FaultSet faults_;
};

}  // namespace mbc::faults
