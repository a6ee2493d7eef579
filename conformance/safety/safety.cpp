#include "safety/safety.h"

#include <fmt/core.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <tuple>

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

int max_quantity(const spec::Spec& s, int fc, int standard) {
  const auto* f = s.profile.function(fc);
  return f && f->max_quantity ? std::min(*f->max_quantity, standard) : standard;
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

// Reads every kept item in runs of adjacent registers of one table, in
// chunks within the profile's limit; a chunk that fails is read register by
// register so one bad address does not hide the rest. Calls
// `got(kept, words)` for each register read and `failed(kept, why)` otherwise.
template <class Got, class Failed>
void read_kept(Target& t, const spec::Spec& s, const std::vector<Snapshot::Kept>& kept, Got&& got, Failed&& failed) {
  for (size_t i = 0; i < kept.size();) {
    const TableOps& o = ops(kept[i].table);
    const int max_read = max_quantity(s, o.read_fc, o.max_read);
    size_t j = i;
    int words = kept[i].words;
    while (j + 1 < kept.size() && kept[j + 1].table == kept[i].table &&
           kept[j + 1].address == kept[j].address + kept[j].words && words + kept[j + 1].words <= max_read) {
      ++j;
      words += kept[j].words;
    }
    std::string why;
    auto chunk = s.profile.function(o.read_fc) ? read_items(t, kept[i].table, kept[i].address, words, why) : std::nullopt;
    if (!s.profile.function(o.read_fc)) why = fmt::format("the profile has no FC {:02} to read {}", o.read_fc, o.name);
    for (size_t k = i, at = 0; k <= j; ++k) {
      const auto& one = kept[k];
      std::optional<std::vector<uint16_t>> w;
      if (chunk)
        w = std::vector<uint16_t>(chunk->begin() + ptrdiff_t(at), chunk->begin() + ptrdiff_t(at + size_t(one.words)));
      else if (s.profile.function(o.read_fc) && j > i)
        w = read_items(t, one.table, one.address, one.words, why);
      at += size_t(one.words);
      if (w) got(one, *w);
      else failed(one, why);
    }
    i = j + 1;
  }
}

// "holding 0x0010-0x001F, 0x0030 (exception 02); coils 0x0000-0x00C7 (no reply)":
// addresses grouped by table and reason, adjacent ones as ranges.
std::string ranges_line(std::vector<std::tuple<Table, std::string, uint16_t, int>> items) {
  std::sort(items.begin(), items.end());
  std::string out;
  for (size_t i = 0; i < items.size();) {
    auto [table, why, a0, w0] = items[i];
    std::string list;
    size_t j = i;
    while (j < items.size() && std::get<0>(items[j]) == table && std::get<1>(items[j]) == why) {
      uint16_t first = std::get<2>(items[j]);
      uint32_t last = uint32_t(first) + uint32_t(std::get<3>(items[j])) - 1;
      while (j + 1 < items.size() && std::get<0>(items[j + 1]) == table && std::get<1>(items[j + 1]) == why &&
             std::get<2>(items[j + 1]) == last + 1) {
        ++j;
        last = uint32_t(std::get<2>(items[j])) + uint32_t(std::get<3>(items[j])) - 1;
      }
      list += fmt::format("{}0x{:04X}", list.empty() ? "" : ", ", first);
      if (last != first) list += fmt::format("-0x{:04X}", last);
      ++j;
    }
    out += fmt::format("{}{} {} ({})", out.empty() ? "" : "; ", ops(table).name, list, why);
    i = j;
  }
  return out;
}

}  // namespace

std::string broadcast_not_applicable(const TargetInfo& target) {
  if (target.framing == &mbc::kRtu) return "";
  return "Modbus TCP: unit 0 addresses a server reached directly, not a broadcast (TCP Implementation Guide "
         "§4.4.1.2); MB-SL v1.02 §2.1 broadcast is checked on RTU targets";
}

Snapshot Snapshot::take(Target& t, const spec::Spec& s, const WritePolicy& policy) {
  Snapshot snap;
  snap.spec_ = &s;
  auto sw = persist_switch_of(s);
  std::vector<Kept> wanted;
  for (const auto& r : s.registers) {
    if (r.access != Access::rw || r.command) continue;
    if (sw && r.table == Table::holding && r.address == sw->first) continue;  // kept apart, restored last
    if (!allowed_write(PolicyFacts{&s, t.info(), policy}, r)) continue;
    wanted.push_back({r.table, r.address, r.words, {0, 0}, reg_name(r)});
  }
  std::stable_sort(wanted.begin(), wanted.end(),
                   [](const Kept& a, const Kept& b) { return std::pair(a.table, a.address) < std::pair(b.table, b.address); });
  std::vector<std::tuple<Table, std::string, uint16_t, int>> unread, unwritable;
  read_kept(
      t, s, wanted,
      [&](const Kept& k, const std::vector<uint16_t>& w) {
        if (!ops(k.table).single_fc) {
          unwritable.emplace_back(k.table, "no Modbus function writes this table", k.address, k.words);
          return;
        }
        Kept kept = k;
        std::copy(w.begin(), w.end(), kept.value);
        snap.kept_.push_back(kept);
      },
      [&](const Kept& k, const std::string& why) { unread.emplace_back(k.table, why, k.address, k.words); });
  // One line each, with ranges: a drive that refuses 60 reads is one finding, not 60.
  if (!unread.empty()) snap.failures_.push_back("could not be read before the run, so not restored: " + ranges_line(unread));
  if (!unwritable.empty()) snap.failures_.push_back("marked writable but cannot be restored: " + ranges_line(unwritable));

  // The switch goes on only on a live device: a reference device's
  // persistence is itself under test.
  if (sw && t.info().live && !snap.kept_.empty()) {
    std::string why;
    auto old = read_items(t, Table::holding, sw->first, 1, why);
    if (!old) {
      snap.failures_.push_back(fmt::format("do-not-persist switch 0x{:04X}: cannot read: {}", sw->first, why));
    } else {
      snap.switch_ = std::pair{sw->first, (*old)[0]};
      uint16_t on = uint16_t(sw->second);
      if (old->front() != on) {
        std::string err = write_verified(t, s, Table::holding, sw->first, std::span(&on, 1),
                                         fmt::format("do-not-persist switch 0x{:04X}", sw->first));
        if (!err.empty()) snap.failures_.push_back(err);
      }
    }
  }
  return snap;
}

std::vector<std::string> Snapshot::restore(Target& t) const {
  std::vector<std::string> failed;
  if (!spec_) return failed;
  // Write back what changed (each write read back at once) ...
  for (const auto& k : kept_) {
    std::span<const uint16_t> want(k.value, size_t(k.words));
    std::string why;
    auto now = read_items(t, k.table, k.address, k.words, why);
    if (now && std::equal(now->begin(), now->end(), want.begin(), want.end())) continue;
    std::string err = write_verified(t, *spec_, k.table, k.address, want, k.name);
    if (!err.empty()) failed.push_back(err);
  }
  // ... then verify the whole snapshot once more: a write with a side effect
  // on another register (a mode that resets a setpoint) shows up here.
  if (failed.empty())
    read_kept(
        t, *spec_, kept_,
        [&](const Kept& k, const std::vector<uint16_t>& w) {
          if (!std::equal(w.begin(), w.end(), k.value, k.value + k.words))
            failed.push_back(fmt::format("{}: restored, but reads {:04X} after the restore (kept {:04X})", k.name,
                                         fmt::join(w, " "), fmt::join(std::span(k.value, size_t(k.words)), " ")));
        },
        [&](const Kept& k, const std::string& why) { failed.push_back(fmt::format("{}: verify failed: {}", k.name, why)); });
  if (switch_) {  // last: until now every restoring write stayed out of EEPROM
    std::string why;
    auto now = read_items(t, Table::holding, switch_->first, 1, why);
    if (!now || now->front() != switch_->second) {
      std::string err = write_verified(t, *spec_, Table::holding, switch_->first, std::span(&switch_->second, 1),
                                       fmt::format("do-not-persist switch 0x{:04X}", switch_->first));
      if (!err.empty()) failed.push_back(err);
    }
  }
  return failed;
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
