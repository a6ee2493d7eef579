#include "safety/safety.h"

#include <fmt/core.h>
#include <fmt/ranges.h>

#include <algorithm>

#include "modbus/judge.h"
#include "modbus/limits.h"
#include "modbus/pdu.h"

namespace mbc::conf {
namespace {

using spec::Access;
using spec::Register;
using spec::Table;

// How a table is read and written (MBAP v1.1b3 §6.1-§6.6, §6.11, §6.12).
// Input registers and discrete inputs have no write function: a register the
// spec marks writable there cannot be put back, and is reported so.
struct TableOps {
  const char* name;
  int read_fc;
  int max_read;  // the standard's limit when the manual states none (§6.1-§6.4)
  int single_fc, multi_fc;
};

const TableOps& ops(Table t) {
  static const TableOps holding{"holding", 3, standard_max_quantity(3), 6, 16},
      coil{"coils", 1, standard_max_quantity(1), 5, 15}, input{"input registers", 4, standard_max_quantity(4), 0, 0},
      discrete{"discrete inputs", 2, standard_max_quantity(2), 0, 0};
  switch (t) {
    case Table::holding: return holding;
    case Table::coil: return coil;
    case Table::input: return input;
    case Table::discrete_input: return discrete;
  }
  return holding;
}

std::string reg_name(const Register& r) {
  return fmt::format("{} 0x{:04X} {}", ops(r.table).name, r.address, r.name.en.empty() ? r.name.zh : r.name.en);
}

// The registers whose persistence a switch suspends (57HS-R 0x0016 = 1).
std::optional<std::pair<uint16_t, int64_t>> persist_switch_of(const spec::Spec& s) {
  for (const auto& r : s.registers)
    if (r.persistence.unless_register) return std::pair{*r.persistence.unless_register, r.persistence.unless_value};
  return std::nullopt;
}

// Sends `req` and judges the reply; nullopt with `why` unless it is a
// well-formed normal reply.
std::optional<Judged> exchange(Target& t, const Bytes& req, std::string& why) {
  Reply r = t.transact(req);
  if (!r.pdu) {
    why = r.silent() ? "no reply" : r.framing_error;
    return std::nullopt;
  }
  Judged j = judge_reply(req, *r.pdu);
  if (j.kind == Judged::Kind::exception) {
    why = fmt::format("exception {:02X}", j.exception_code);
    return std::nullopt;
  }
  if (!j.ok()) {
    why = j.problems.empty() ? "malformed reply" : j.problems.front();
    return std::nullopt;
  }
  return j;
}

// `count` items of `table` at `address` (bits as 0/1); nullopt with `why`.
std::optional<std::vector<uint16_t>> read_items(Target& t, Table table, uint16_t address, int count, std::string& why) {
  Bytes req = read_request(uint8_t(ops(table).read_fc), address, uint16_t(count));
  auto j = exchange(t, req, why);
  if (!j) return std::nullopt;
  std::vector<uint16_t> got = j->registers;
  for (bool b : j->bits) got.push_back(b ? 1 : 0);
  if (got.size() != size_t(count)) {
    why = "malformed reply";
    return std::nullopt;
  }
  return got;
}

// Writes `values` at `address`: the single write (FC 05/06) for one item when
// the profile has it, else the multiple write (FC 15/16); a 2-word value is
// written whole, never split in two FC 06.
bool write_items(Target& t, const spec::Spec& s, Table table, uint16_t address, std::span<const uint16_t> values,
                 std::string& why) {
  const TableOps& o = ops(table);
  if (!o.single_fc) {
    why = fmt::format("no Modbus function writes {}", o.name);
    return false;
  }
  bool single = s.profile.function(o.single_fc) != nullptr, multi = s.profile.function(o.multi_fc) != nullptr;
  Bytes req;
  if (values.size() == 1 && (single || !multi)) {
    req = table == Table::coil ? write_single_coil(address, values[0] != 0) : write_single_register(address, values[0]);
  } else if (multi && table == Table::coil) {
    bool bits[2] = {values[0] != 0, values.size() > 1 && values[1] != 0};
    req = write_multiple_coils(address, std::span<const bool>(bits, values.size()));
  } else if (multi) {
    req = write_multiple_registers(address, values);
  } else {
    why = fmt::format("the profile has no FC {} to write a 2-word value whole", o.multi_fc);
    return false;
  }
  return exchange(t, req, why).has_value();
}

// Writes and reads back; the failure message, empty on success.
std::string write_verified(Target& t, const spec::Spec& s, Table table, uint16_t address,
                           std::span<const uint16_t> values, const std::string& what) {
  std::string why;
  if (!write_items(t, s, table, address, values, why)) return fmt::format("{}: write failed: {}", what, why);
  auto back = read_items(t, table, address, int(values.size()), why);
  if (!back) return fmt::format("{}: read-back failed: {}", what, why);
  if (!std::equal(back->begin(), back->end(), values.begin(), values.end()))
    return fmt::format("{}: wrote {:04X}, reads back {:04X}", what, fmt::join(values, " "), fmt::join(*back, " "));
  return "";
}

}  // namespace

std::string broadcast_not_applicable(const TargetInfo& target) {
  if (target.framing == &mbc::kRtu) return "";
  return "Modbus TCP: unit 0 addresses a server reached directly, not a broadcast (TCP Implementation Guide "
         "§4.4.1.2); MB-SL v1.02 §2.1 broadcast is checked on RTU targets";
}

std::optional<std::vector<uint16_t>> read_table(Target& t, Table table, uint16_t address, int count, std::string& why) {
  return read_items(t, table, address, count, why);
}

std::string write_table_verified(Target& t, const spec::Spec& s, Table table, uint16_t address,
                                 std::span<const uint16_t> values, const std::string& what) {
  return write_verified(t, s, table, address, values, what);
}

std::optional<std::pair<uint16_t, int64_t>> persist_switch(const spec::Spec& s) { return persist_switch_of(s); }

std::string register_label(const Register& r) { return reg_name(r); }

}  // namespace mbc::conf
