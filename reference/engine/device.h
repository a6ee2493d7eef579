// A reference Modbus device driven by a spec: register storage, access
// rules, ranges, per-function limits and the device's own exception policy,
// all taken from the spec at load time. Behaviour that a register table
// cannot state (motion, homing, save/reset commands) lives in one small
// Behaviour per device under reference/devices/.
//
// The engine never sees a socket: it takes one RTU ADU (or one PDU) and
// returns the reply, or nothing for silence. Transports live in reference/serve.
#pragma once

#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <unordered_map>
#include <vector>

#include "engine/virtual_axis.h"
#include "modbus/hex.h"
#include "spec.h"

namespace mbc::ref {

class Device;

// Device behaviour beyond the register table. Every hook has a default that
// does nothing, so a device whose spec says everything needs no Behaviour.
class Behaviour {
 public:
  virtual ~Behaviour() = default;
  // A write of [address, address+count) is about to be stored; the new raw
  // words are `values`. Return an exception code to refuse it (nothing is stored).
  virtual std::optional<uint8_t> check_write(const Device&, uint16_t address, std::span<const uint16_t> values) {
    return std::nullopt;
  }
  // [address, address+count) was written and stored (commands act here).
  virtual void on_write(Device&, uint16_t address, uint16_t count) {}
  // [address, address+count) is about to be read: refresh computed registers.
  virtual void before_read(Device&, uint16_t address, uint16_t count) {}
  // The virtual clock moved forward by dt microseconds.
  virtual void advance(Device&, uint64_t dt_us) {}
  // After the engine restored registers on power-up (volatile = defaults,
  // persistent = stored image).
  virtual void power_on(Device&) {}
  // A fault the device detects, caused out of band (Device::trip_fault()):
  // true when the behaviour has a fault to enter (a control model with a
  // `fault` step), false when it has none.
  virtual bool trip_fault(Device&) { return false; }
};

class ControlTweak;

// The behaviour of a device: the one registered for its id
// (reference/devices/), or a no-op one; and, when its spec has `control:`,
// the control executor around it (engine/control.h), which `tweak` (the
// state-machine faults) may bend.
std::unique_ptr<Behaviour> make_behaviour(const spec::Spec& spec, std::shared_ptr<const ControlTweak> tweak = nullptr);

// Counters of MB over Serial Line v1.02 §6.1 (FC 08 sub-functions 11-18).
struct DiagnosticCounters {
  uint16_t bus_messages = 0;
  uint16_t bus_comm_errors = 0;  // CRC errors
  uint16_t exceptions = 0;
  uint16_t server_messages = 0;
  uint16_t no_responses = 0;
  uint16_t nak = 0;
  uint16_t busy = 0;
  uint16_t overruns = 0;
};

class Device {
 public:
  Device(spec::Spec spec, uint8_t slave_id);
  Device(spec::Spec spec, uint8_t slave_id, std::unique_ptr<Behaviour> behaviour);
  ~Device();
  Device(Device&&) noexcept;
  Device& operator=(Device&&) noexcept;

  const spec::Spec& spec() const { return spec_; }
  uint8_t slave_id() const { return slave_id_; }
  void set_slave_id(uint8_t id) { slave_id_ = id; }

  // One RTU ADU (slave, PDU, CRC). Frames for other slave ids, broadcast
  // frames and frames the policy answers with silence return nullopt.
  std::optional<Bytes> handle_rtu(std::span<const uint8_t> adu);
  // One PDU addressed to this device (broadcast = sent to address 0).
  std::optional<Bytes> handle_pdu(std::span<const uint8_t> pdu, bool broadcast = false);

  // The same two, with the reply written into the caller's storage and
  // nothing allocated (a server loop, a fuzz harness): they return the
  // reply's length, 0 for silence (no reply is empty). `reply` must not
  // overlap the request and must hold max_reply_pdu() bytes (handle_pdu_into)
  // or max_reply_pdu() + 3 (handle_rtu_into: address and CRC); a shorter one
  // throws std::length_error before the request is acted on.
  size_t handle_rtu_into(std::span<const uint8_t> adu, std::span<uint8_t> reply);
  size_t handle_pdu_into(std::span<const uint8_t> pdu, std::span<uint8_t> reply, bool broadcast = false);
  // The longest reply PDU this device gives: kMaxPdu (MBAP v1.1b3 §4.1),
  // unless its spec's identification strings make an FC 17 / FC 43 reply longer.
  size_t max_reply_pdu() const { return max_reply_pdu_; }

  // Raw register image (holding table; the other tables below).
  uint16_t word(uint16_t address) const { return holding_[address]; }
  void set_word(uint16_t address, uint16_t value);  // no policy checks, no hooks
  uint16_t input_word(uint16_t address) const;
  void set_input_word(uint16_t address, uint16_t value);
  bool coil(uint16_t address) const;
  void set_coil(uint16_t address, bool on);
  bool discrete_input(uint16_t address) const;
  void set_discrete_input(uint16_t address, bool on);

  // A register's value through its type and word order (float32 as its bits).
  int64_t value(const spec::Register& r) const;
  void set_value(const spec::Register& r, int64_t v);
  double float_value(const spec::Register& r) const;
  // By address (holding table); throws std::out_of_range when unmapped.
  int64_t value_at(uint16_t address) const;
  void set_value_at(uint16_t address, int64_t v);

  // The whole holding-register image, for "rejection changes nothing" checks.
  std::map<uint16_t, uint16_t> holding_image() const;

  // Virtual clock: behaviours move the axis only when time advances.
  void advance(uint64_t dt_us);
  uint64_t now_us() const { return now_us_; }
  Axis& axis() { return axis_; }
  const Axis& axis() const { return axis_; }

  // Power cycle: volatile registers return to defaults, persistent ones keep
  // what was stored, "after power cycle" settings take effect.
  void power_cycle();
  // A fault the drive detects, caused from outside the bus (a layout such as
  // CiA 402's gives no way to cause one through Modbus): the control model's
  // `fault` step is taken. False when the device has no such step.
  bool trip_fault();
  // Restores every register to the spec's default (and clears the stored image).
  void factory_reset();
  // Copies current persistent registers into the stored image (a save command).
  void save_persistent();
  // The stored (EEPROM/flash) image: address -> word.
  const std::map<uint16_t, uint16_t>& stored_image() const { return stored_; }
  void load_stored_image(std::map<uint16_t, uint16_t> image);
  // Counts EEPROM/flash writes (each stored word written counts one).
  uint64_t eeprom_writes() const { return eeprom_writes_; }

  const DiagnosticCounters& counters() const { return counters_; }
  bool listen_only() const { return listen_only_; }

  // The register the spec gives `key` (a stable name behaviour code uses
  // instead of repeating addresses); throws std::out_of_range if absent.
  const spec::Register& reg_by_key(std::string_view key) const;
  const spec::Register* find_by_key(std::string_view key) const;
  int64_t value_of(std::string_view key) const { return value(reg_by_key(key)); }
  void set_value_of(std::string_view key, int64_t v) { set_value(reg_by_key(key), v); }

  // The register covering `address`, if the spec maps it.
  const spec::Register* reg(uint16_t address, spec::Table table = spec::Table::holding) const;

 private:
  spec::Spec spec_;
  std::vector<uint16_t> holding_, input_;  // 65536 words each
  std::vector<uint8_t> coils_, discrete_;  // 65536 bits each, one byte per bit
  // What a request reads of the spec, resolved once at construction so that
  // the hot path does no fact lookup, string compare or search per word:
  // - per table, the mapped addresses as runs of neighbouring registers that
  //   allow the same access (a read or write is checked run by run);
  // - per function code (0..127), whether the profile lists it, and its
  //   quantity limits capped by the standard's (MBAP v1.1b3 §6);
  // - per violation, the answer: the device's policy, else the standard's
  //   (spec/devices/modbus-standard.yaml), as an exception code or silence (-1).
  struct MappedRun {
    uint16_t first = 0, last = 0;
    bool readable = true, writable = true;
  };
  struct FunctionLimits {
    bool supported = false;
    int max_quantity = 0, max_read = 0, max_write = 0;
  };
  void resolve_spec();
  // handle_pdu_into once `out` is known to hold max_reply_pdu_ bytes.
  size_t reply_pdu(std::span<const uint8_t> pdu, uint8_t* out, bool broadcast);
  // The span of each table written since the last power cycle, so that a
  // power cycle clears that instead of 4 x 64 Ki words (a fuzz harness power
  // cycles its device before every input).
  struct Touched {
    uint32_t lo = 0x10000, hi = 0;  // [lo, hi); empty when lo >= hi
    void mark(uint32_t address, uint32_t count = 1) {
      if (address + count > 0x10000) address = 0, count = 0x10000;
      lo = std::min(lo, address);
      hi = std::max(hi, address + count);
    }
  };
  std::array<Touched, 4> touched_{};
  // What a power cycle writes, per table: each register's default as the
  // cells it is stored in (address, word or bit), and the span they cover;
  // converted once here, not per power cycle (a fuzz harness cycles per input).
  struct Cell {
    uint16_t address, value;
  };
  std::array<std::vector<Cell>, 4> power_on_;
  std::array<Touched, 4> power_on_span_{};
  void write_power_on_image();
  void put_cell(spec::Table t, uint16_t address, uint16_t value);
  // The holding addresses of persistent registers, ascending.
  std::vector<uint16_t> persistent_words_;
  // Register by key. The views point into spec_'s registers, which stay put:
  // spec_ is never changed, and moving a Device moves the vector's storage.
  std::unordered_map<std::string_view, const spec::Register*> by_key_;
  std::array<int32_t, 4> last_address_{};  // per table, from the spec; -1: nothing mapped
  std::vector<MappedRun> runs_[4];
  // Per table and 256-address page, the index in runs_ of the first run that
  // ends in or after that page: an address's run is found from there in a
  // step or two instead of a search of the whole map.
  std::array<std::array<uint32_t, 256>, 4> page_runs_{};
  size_t max_reply_pdu_ = 0;
  std::array<FunctionLimits, 128> functions_{};
  std::array<int16_t, 16> answers_{};  // by Violation; -1: silence
  uint8_t slave_id_;
  std::unique_ptr<Behaviour> behaviour_;
  Axis axis_;
  uint64_t now_us_ = 0;
  std::map<uint16_t, uint16_t> stored_;
  uint64_t eeprom_writes_ = 0;
  DiagnosticCounters counters_;
  bool listen_only_ = false;
  friend struct Engine;
};

// Several devices on one RS-485 line: broadcast reaches every device and is
// never answered; frames for absent ids and corrupted frames get silence.
class Bus {
 public:
  void add(std::unique_ptr<Device> d) { devices_.push_back(std::move(d)); }
  std::optional<Bytes> handle_rtu(std::span<const uint8_t> adu);
  // Modbus TCP unit addressing: the unit id picks the device. Unit 0 is a
  // broadcast to every device, except where the bus has one device: then the
  // server is reached directly and 0, like 0xFF, addresses it (Modbus
  // Messaging on TCP/IP Implementation Guide V1.0b §4.4.1.2).
  std::optional<Bytes> handle_pdu(uint8_t unit, std::span<const uint8_t> pdu);
  // The same two into the caller's storage, as Device::handle_rtu_into and
  // handle_pdu_into: the reply's length, 0 for silence; `reply` holds
  // max_reply_pdu() (+ 3 for RTU) bytes, the most any device on the bus needs.
  size_t handle_rtu_into(std::span<const uint8_t> adu, std::span<uint8_t> reply);
  size_t handle_pdu_into(uint8_t unit, std::span<const uint8_t> pdu, std::span<uint8_t> reply);
  size_t max_reply_pdu() const;
  // The device a TCP unit id 0 or 0xFF reaches directly (one device served), or null.
  Device* direct(uint8_t unit);
  Device* find(uint8_t slave_id);
  std::vector<std::unique_ptr<Device>>& devices() { return devices_; }
  void advance(uint64_t dt_us);

 private:
  std::vector<std::unique_ptr<Device>> devices_;
};

}  // namespace mbc::ref
