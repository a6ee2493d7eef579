// The resolved device spec: plain data, no behaviour. Everything the
// reference devices, the conformance generators, the fuzz corpora and the
// reports know about a device comes from one of these structs, loaded from
// spec/devices/<id>.yaml by load_spec() (see spec/README.md for the language).
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace mbc::spec {

struct SourceLoc {
  int line = 0;  // 1-based; 0 = unknown
  int col = 0;
};

struct Name {
  std::string zh;
  std::string en;
};

enum class Table { holding, input, coil, discrete_input };
enum class Access { ro, rw, wo, command };
enum class DataType { u16, s16, u32, s32, f32, bitfield, enumeration, bit };
enum class WordOrder { none, high_first, low_first };
enum class Store { none, eeprom, flash };
enum class PersistBy { none, on_write, save_command };
enum class TakesEffect { immediate, power_cycle };

struct Range {
  double min = 0;
  double max = 0;
  bool operator==(const Range&) const = default;
};

// Where a fact comes from (spec/README.md, "Where each fact comes from").
// stated: the source prints it (a register table, or `quote`); inferred: our
// reading (`why`, and the sections `searched`); observed: probed on a live
// target (`why` says how), which counts as inferred; either: the source
// prints two readings (`readings`, as the JSON text of each).
enum class Basis { stated, inferred, observed, either };
struct FactBasis {
  Basis basis = Basis::stated;
  std::string why;       // inferred / observed
  std::string searched;  // inferred: the sections searched
  std::string quote;     // stated: the source's words, when outside a table
  std::string section;   // where; empty = the owner's section
  std::string erratum;   // either: the erratum recording the contradiction
  std::vector<std::string> readings;  // either: each reading as JSON text
  SourceLoc loc;

  bool is_inferred() const { return basis == Basis::inferred || basis == Basis::observed; }
};
const char* to_string(Basis);

// The facts of a register a case can rely on (`basis:` keys).
// persistence_unless: that the do-not-persist switch (`persistence.unless`)
// holds a write back; `persistence` itself is the storing with the switch off.
enum class Fact { read, write, range, default_value, word_order, type, takes_effect, persistence, persistence_unless };
inline constexpr Fact kRegisterFacts[] = {Fact::read,       Fact::write,        Fact::range,
                                          Fact::default_value, Fact::word_order, Fact::type,
                                          Fact::takes_effect, Fact::persistence,  Fact::persistence_unless};
const char* to_string(Fact);  // the `basis:` key ("default" for default_value)

struct EnumValue {
  int64_t value = 0;
  Name name;
  std::string note;
};

struct Enumeration {
  std::string id;
  std::string section;
  std::vector<EnumValue> values;
  SourceLoc loc;
};

struct BitField {
  int lo = 0;  // lowest bit
  int hi = 0;  // highest bit (== lo for a single bit)
  // A stable name behaviour code uses instead of the bit number (unique in
  // its bitfield; empty when none is given).
  std::string key;
  Name name;
  bool reserved = false;
  std::optional<int64_t> default_value;
  std::string enum_id;  // values of a multi-bit field, if coded
  std::string erratum;
};

struct Bitfield {
  std::string id;
  std::string section;
  std::vector<BitField> fields;
  SourceLoc loc;

  const BitField* field(std::string_view key) const {
    for (const auto& f : fields)
      if (!f.key.empty() && f.key == key) return &f;
    return nullptr;
  }
};

struct Persistence {
  Store store = Store::none;
  PersistBy by = PersistBy::none;
  std::optional<uint16_t> command;  // the save register, when by == save_command
  // Persistence is suspended while register `unless_register` holds
  // `unless_value` (57HS-R 0x0016, "do not update EEPROM").
  std::optional<uint16_t> unless_register;
  int64_t unless_value = 0;
  std::string section;
};

struct Command {
  std::string effect;
  std::optional<int64_t> reads_back;
  bool motion = false;
  bool eeprom = false;
  std::vector<int64_t> values;
};

struct Register {
  uint16_t address = 0;  // wire (PDU) address
  std::string key;       // stable name for behaviour code (blocks: key[1], key[2], ...)
  int words = 1;         // 1 or 2
  Table table = Table::holding;
  Name name;
  Access access = Access::rw;
  DataType type = DataType::u16;
  WordOrder word_order = WordOrder::none;
  std::optional<Range> range;
  std::optional<double> default_value;
  std::string unit;
  double scale = 1;
  Persistence persistence;
  TakesEffect takes_effect = TakesEffect::immediate;
  std::string enum_id;      // for type enumeration (inline lists get a generated id)
  std::string bitfield_id;  // for type bitfield
  std::optional<Command> command;
  std::map<std::string, std::string> printed;  // field -> text as printed
  std::vector<std::string> errata;
  std::string note;
  std::string section;
  // Facts not plainly stated by the register's table row; absent = stated.
  std::map<Fact, FactBasis> basis;
  // `either` readings of range / default / word_order (each non-empty only then).
  std::vector<Range> range_readings;
  std::vector<double> default_readings;
  std::vector<WordOrder> word_order_readings;
  int block_index = -1;  // index inside a `count:` block, -1 if not from one
  SourceLoc loc;
  std::string origin;  // JSON pointer of the declaration ("/registers/7")

  bool is_signed() const { return type == DataType::s16 || type == DataType::s32; }
  // The basis of a fact: its `basis:` entry, else stated by `section`.
  FactBasis basis_of(Fact f) const;
  uint32_t last_address() const { return uint32_t(address) + uint32_t(words) - 1; }
  // word_order as modbus/words.h's flag: the word at the lower address holds the low 16 bits.
  bool low_word_first() const { return word_order == WordOrder::low_first; }
};

// What the device answers to one kind of violation.
struct PolicyEntry {
  enum class Kind { exception, silent, unspecified } kind = Kind::unspecified;
  int code = 0;  // exception code when kind == exception
  std::string section;
  std::string erratum;
  // stated (with basis.quote), inferred, observed, or either (then
  // `readings` holds each reading, and kind/code are the first one's).
  FactBasis basis;
  std::vector<PolicyEntry> readings;
  SourceLoc loc;
};

// The kinds of violation, in the order reports list them.
enum class Violation {
  unsupported_function,
  unmapped_address,
  address_past_map,
  quantity_zero,
  quantity_over_limit,
  value_out_of_range,
  write_read_only,
  read_write_only,
  crc_error,
  wrong_byte_count,
};
inline constexpr Violation kAllViolations[] = {
    Violation::unsupported_function, Violation::unmapped_address,   Violation::address_past_map,
    Violation::quantity_zero,        Violation::quantity_over_limit, Violation::value_out_of_range,
    Violation::write_read_only,      Violation::read_write_only,     Violation::crc_error,
    Violation::wrong_byte_count};
const char* to_string(Violation v);

struct FunctionCode {
  int code = 0;
  std::optional<int> max_quantity;
  std::optional<int> max_read_quantity;   // FC 23
  std::optional<int> max_write_quantity;  // FC 23
  std::vector<int> subfunctions;          // FC 08
  std::vector<int> mei_types;             // FC 43
  std::string note;
  std::string section;
  std::string erratum;
  std::map<std::string, FactBasis> basis;  // "max_quantity", ...; absent = stated
  SourceLoc loc;

  FactBasis basis_of(const std::string& fact) const;
};

struct ExceptionCodeMeaning {
  int code = 0;
  Name name;
  std::string meaning;
  std::string section;
};

struct Profile {
  std::string section;
  std::vector<FunctionCode> function_codes;
  std::map<Violation, PolicyEntry> exception_policy;
  std::vector<ExceptionCodeMeaning> exception_codes;

  const FunctionCode* function(int code) const {
    for (const auto& f : function_codes)
      if (f.code == code) return &f;
    return nullptr;
  }
  PolicyEntry policy(Violation v) const {
    auto it = exception_policy.find(v);
    return it == exception_policy.end() ? PolicyEntry{} : it->second;
  }
};

struct SerialSetting {
  uint16_t register_address = 0;
  std::string setting;  // baud_rate | frame_format | slave_id
  std::vector<std::pair<int64_t, std::string>> encoding;  // raw value -> meaning
  std::string section;
};

struct Serial {
  std::string section;
  int slave_min = 1, slave_max = 247;
  std::optional<int> slave_default;
  std::string slave_set_by;
  std::string slave_section;
  std::optional<int> broadcast_address;
  std::string broadcast_writes = "unspecified";  // applied | ignored | unspecified
  std::string broadcast_reply = "unspecified";   // none | unspecified
  std::string broadcast_section;
  std::vector<int> baud_rates;
  std::optional<int> baud_default;
  std::string baud_section;
  std::vector<std::string> frame_formats;  // "8N1", "8E1", ...
  std::optional<std::string> frame_default;
  std::string frame_section;
  std::vector<SerialSetting> settings;
};

struct RegisterValue {
  uint16_t address = 0;
  double value = 0;
  Table table = Table::holding;  // given:/after: default to the function code's table
  bool table_set = false;
};

struct Example {
  std::string id;
  std::string section;
  std::string does;
  std::string request;   // uppercase hex, as printed
  std::optional<std::string> response;  // as printed; absent when none printed
  std::vector<RegisterValue> given;
  std::vector<RegisterValue> after;
  std::string sequence;
  int step = 0;
  std::vector<std::string> errata;
  // The reading tests use when the printed frame is an erratum.
  std::optional<std::string> resolved_request;
  std::optional<std::string> resolved_response;
  bool resolved_silent = false;
  bool no_reply = false;  // the source says the device does not answer this frame
  // The kind of violation the frame provokes (`exercises:`, else derived by
  // the loader: an unsupported function code, a deliberately bad CRC, or an
  // exception reply whose code only one policy kind gives). An example
  // inherits the `either` of the policy it exercises (rule erratum-contested).
  std::optional<Violation> exercises;
  // either: the device may answer as printed or as `resolved` (readings
  // "printed", "resolved"); inferred/observed: the frame is not printed.
  FactBasis basis;
  SourceLoc loc;
  std::string origin;  // JSON pointer of the declaration ("/examples/3")

  bool has_resolution() const {
    return resolved_request || resolved_response || resolved_silent;
  }
};

struct Erratum {
  std::string id;
  std::string section;
  std::string kind;
  std::string printed;
  std::string resolved;
  std::string why;
  // What the contradiction puts in doubt, of what cites it (`contests:`):
  // register fact keys (read, write, range, ...), `supported`,
  // `max_quantity`, `policy`, `example`. Absent: everything that cites it;
  // empty: nothing a case relies on (recorded only).
  std::vector<std::string> contests;
  bool contests_given = false;
  // The printed frames (example ids) the resolution rests on (`settled_by:`):
  // a fact the erratum contests may then stay stated. A bad CRC is settled
  // by the CRC routine itself.
  std::vector<std::string> settled_by;
  SourceLoc loc;

  bool settled() const { return !settled_by.empty() || kind == "bad_crc"; }
  // Whether this erratum puts `what` in doubt where cited ("range", "policy", ...).
  bool contests_fact(const std::string& what) const;
};

struct Manual {
  std::string file;
  // manual | csv | wb-mqtt-serial (an imported map: every unmarked fact
  // inferred) | discover (every unmarked fact observed)
  std::string source = "manual";
  std::string address_notation;  // hex | decimal
  std::string addressing_note;
  std::string erratum;  // the erratum recording how the addressing note is read (every register's address rests on it)
};

// What FC 17 and FC 43/14 return (MBAP v1.1b3 §6.13, §6.21).
struct Identification {
  std::string vendor_name, product_code, revision = "1.0";
  std::optional<int> server_id;  // default: the slave id
  int run_indicator = 0xFF;
  std::string additional_data;
};

struct Device {
  Identification identification;
  std::string id;
  std::string vendor;
  std::string title;
  std::vector<std::string> models;
  Manual manual;
  std::string section;
};

// A write of `value` to the register named by spec `key`, then `settle_us`
// of (virtual) time before its effect can be read back.
struct RegisterWrite {
  std::string key;
  int64_t value = 0;
  uint64_t settle_us = 0;
  std::string section;
  SourceLoc loc;
};

// How a position move is set up, started, stopped and watched: the facts
// motion properties need that a register table cannot state (`control:
// motion:` in the language). Registers by key; values raw; distances and
// positions in pulses.
struct MotionOperations {
  std::string section;
  std::vector<RegisterWrite> assumes;  // values the figures below assume (e.g. the microstep)
  std::vector<RegisterWrite> setup;    // writes that set the profile before a move, in order
  std::string distance_key, reverse_distance_key;  // reverse: for negative moves, when separate
  bool signed_distance = false;
  std::optional<RegisterWrite> start_forward, start_reverse;  // none: the distance write starts
  int64_t max_distance = 4000;
  std::string position_key, position_high_key;  // high: the high word in a second register
  double max_speed_pulses_per_s = 0;  // what `setup` configures
  double decel_seconds = 0;           // a normal stop from that speed
  // Where decel_seconds comes from (`decel:`): only a stated time is held
  // against the drive; inferred, or no `decel:` at all (not stated), is observed.
  FactBasis decel_basis = not_stated_decel();
  static FactBasis not_stated_decel() {
    FactBasis b;
    b.basis = Basis::inferred;
    b.why = "not stated: the spec gives no decel: with the section that states the stop time";
    return b;
  }
  std::optional<RegisterWrite> stop, emergency_stop;
  std::string status_key;
  uint16_t running_mask = 0;
  bool running_when_set = true;  // false: the mask is a "motion complete" bit
  uint16_t in_position_mask = 0;
  bool positioning_needs_homing = false;  // positioning refused until homed
  std::string position_command_key;
  SourceLoc loc;
};

// ---- Control ----
// A drive's control as a state machine (`control:` in the language,
// spec/README.md "Control"): the states and the status reading that names
// each, the commands and the register write that gives each, the transitions
// between states, and the modes of operation with their set-points and what
// proves them. Plain data, resolved by the loader: a device that names a
// library profile (`control: {profile: cia402, registers: {...}}`) gets the
// profile's states, commands and transitions with its own register keys.
//
// Every entry carries its section and its basis (stated, inferred, either):
// a MUST verdict on a transition rests on a stated entry only.

// A reading of one register that holds when (word & mask) == value.
struct StatusMatch {
  std::string register_key;  // a register of the device (after the profile's mapping)
  uint16_t mask = 0xFFFF;
  uint16_t value = 0;
  bool matches(uint16_t word) const { return (word & mask) == value; }
};

struct ControlState {
  std::string id;  // "switch_on_disabled"; unique in the section
  Name name;       // as printed ("Switch on disabled")
  // Every reading must hold (CiA 402: statusword & 0x4F or 0x6F).
  std::vector<StatusMatch> status;
  bool motion = false;  // the axis may move (or be held under torque) in this state
  bool fault = false;   // a fault state (left by a fault reset only)
  std::string section;
  FactBasis basis;
  SourceLoc loc;
};

// How a written word gives a command.
//  level: the word's bits select it (CiA 402 Shutdown, 0xxx x110): written
//         again, the same word gives the same command;
//  edge:  the bits in `edge_mask` rising from 0 to 1 between the last word
//         written and this one (CiA 402 Fault reset, bit 7 0 -> 1);
//  write: every write of a matching word acts, whatever was there before
//         (a start register: 57HS-R 0x0027).
enum class Trigger { level, edge, write };
const char* to_string(Trigger);

struct ControlCommand {
  std::string id;  // "shutdown"
  Name name;
  std::string register_key;
  // The word selects the command when (word & mask) == value. To give the
  // command, a master writes `value` (bits outside `mask` cleared) unless
  // `write` is given.
  uint16_t mask = 0xFFFF;
  uint16_t value = 0;
  std::optional<uint16_t> write;
  Trigger trigger = Trigger::level;
  uint16_t edge_mask = 0;  // edge: the bits whose 0 -> 1 change acts
  // May set the axis moving (with the set-points of the active mode); a
  // motion-free walk sends it only where `moves_only_with` holds nothing.
  bool motion = false;
  // The registers that set how it moves when they are not its modes'
  // set-points: the frame policy lets a motion command out without
  // --allow-motion only once these (absent: every mode's set-points) were
  // written 0. Empty: the manual does not say what sets its speed (Rieding's
  // internal speeds 1-3), so no write makes it safe.
  std::optional<std::vector<std::string>> setpoint_keys;
  // Stops the axis from every moving state (quick stop, emergency stop).
  bool stops = false;
  std::optional<double> stop_within_ms;  // stated: stopped within this time from the stated top speed
  std::string section;
  FactBasis basis;
  SourceLoc loc;

  uint16_t word() const { return write.value_or(value); }
  bool selected_by(uint16_t word) const { return (word & mask) == value; }
};

// A condition on a register's value (a transition taken only for some
// quick stop option codes: CiA 402 transitions 12 and 16).
struct ValueCondition {
  std::string register_key;
  std::vector<int64_t> values;  // one of these
};

struct ControlTransition {
  std::string id;       // as the source numbers it ("2", "3+4"); unique in the section
  std::string from;     // a state id, or "*" for every state
  std::string command;  // a command id; empty for an automatic step
  // Automatic steps: what ends them. "power_on" (after power-up),
  // "motion_done" (the axis stopped: quick stop complete), "fault" (a fault
  // the drive detects), "reaction_done" (its fault reaction completed), "time".
  std::string event;
  std::string to;
  std::optional<double> within_ms;  // an automatic step's stated time
  std::vector<ValueCondition> when;  // all must hold
  bool motion = false;  // taking it may move the axis
  std::string section;
  FactBasis basis;
  SourceLoc loc;

  bool automatic() const { return command.empty(); }
};

// A mode of operation: how it is selected, its set-points, what starts it
// and what proves it.
struct ControlMode {
  std::string id;  // position | speed | torque | homing
  std::optional<RegisterWrite> select;  // the write that selects it (CiA 402 6060h = 1)
  std::string display_key;  // the register that shows the active mode (6061h), if any
  std::vector<std::string> setpoint_keys;  // target position, target velocity, ...
  std::string actual_key;  // what proves it: the position or speed actual register
  std::string start_command;  // a command id that starts it (CiA 402 bit 4 new set-point), if any
  std::optional<StatusMatch> done;  // target reached, in position, homing attained
  // States in which selecting the mode is accepted; empty: every state.
  std::vector<std::string> select_in;
  std::string section;
  FactBasis basis;
  SourceLoc loc;
};

// What a command not defined in a state does (the profile says): ignored
// (state unchanged, the write is stored) or refused with an exception.
struct UndefinedCommand {
  enum class Kind { ignored, exception } kind = Kind::ignored;
  int code = 0;
  std::string section;
  FactBasis basis;
};

struct Control {
  std::string profile;  // the library profile it was built from (spec/profiles/<id>.yaml), if any
  std::string section;
  std::vector<ControlState> states;
  std::vector<ControlCommand> commands;
  std::vector<ControlTransition> transitions;
  std::vector<ControlMode> modes;
  std::string initial;  // the state after power-on, once its automatic steps ran
  std::string safe;     // where a restore goes first (no motion, no torque)
  UndefinedCommand undefined;
  // The stated top speed the stop times assume (pulses or units per s), when stated.
  std::optional<double> top_speed;
  // A position move, set up, started, stopped and watched (the motion
  // properties' facts), `control.motion` in the language.
  std::optional<MotionOperations> motion;
  // `control.no_motion`: why the manual gives no `motion` (Rieding: the
  // distance-to-position scale is not printed); the motion properties say so.
  struct Unstated {
    std::string section, why;
  };
  std::optional<Unstated> no_motion;
  SourceLoc loc;

  const ControlState* state(const std::string& id) const;
  const ControlCommand* command(const std::string& id) const;
  const ControlMode* mode(const std::string& id) const;
  // The transitions out of `state` given by `command` (including "*" ones).
  std::vector<const ControlTransition*> transitions_on(const std::string& state, const std::string& command) const;
};

// Device operations: which write saves, which restores factory defaults
// (`operations:`; absent when the manual documents none). How a move is made
// is the control's (`control.motion`).
struct Operations {
  std::string section;
  // Writes a master makes, in order, before using the device (a template's
  // `setup`): each a register write, so the safety rules gate it like any other.
  std::vector<RegisterWrite> setup;
  std::optional<RegisterWrite> save;
  std::optional<RegisterWrite> factory_reset;
};

// How long a master waits, as the source states it (`timing:`): for a
// reply, for the rest of a frame, and between two frames.
struct Timing {
  std::optional<double> response_timeout_ms, frame_timeout_ms, guard_interval_us;
  // The drive's own response time, where the manual states one (request's end
  // to reply's start): conformance/timing/ judges it as a MUST.
  std::optional<double> response_time_ms;
  std::string section;
};

struct Spec {
  std::string path;  // file it was loaded from
  Device device;
  Serial serial;
  Profile profile;
  std::vector<Enumeration> enums;
  std::vector<Bitfield> bitfields;
  std::vector<Register> registers;  // resolved: blocks expanded, sorted by (table, address)
  std::vector<Example> examples;
  std::vector<Erratum> errata;
  Operations operations;
  // The drive's control state machine (`control:`); absent when the spec has none.
  std::optional<Control> control;
  Timing timing;

  const Register* find_register(uint16_t address, Table table = Table::holding) const;
  // The register whose words cover `address` (a 2-word register covers two).
  const Register* register_covering(uint16_t address, Table table = Table::holding) const;
  const Register* find_by_key(const std::string& key) const;
  const Enumeration* find_enum(const std::string& id) const;
  const Bitfield* find_bitfield(const std::string& id) const;
  const Erratum* find_erratum(const std::string& id) const;
  // Highest wire address any register of `table` covers, if any.
  std::optional<uint16_t> last_address(Table table = Table::holding) const;
};

// The data table a function code addresses (MBAP v1.1b3 §4.3, §6); FC 07's
// exception status outputs are coils here (modbus-standard maps them so).
Table table_for_function(int function_code);

const char* to_string(Table);
const char* to_string(Access);
const char* to_string(DataType);
const char* to_string(WordOrder);

}  // namespace mbc::spec
