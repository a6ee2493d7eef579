#include "safety/safety.h"

#include <fmt/core.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <set>

#include "master/pdu.h"

namespace mbc::conf {
namespace {

using spec::Access;
using spec::Register;
using spec::Table;

// MBAP v1.1b3 §6.3: FC 03 reads at most 125 registers when the manual states no limit.
constexpr int kStandardMaxRead = 125;

std::string reg_name(const Register& r) {
  return fmt::format("0x{:04X} {}", r.address, r.name.en.empty() ? r.name.zh : r.name.en);
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

// FC 03 of `count` words at `address`; the words, or nullopt with `why`.
std::optional<std::vector<uint16_t>> read_words(Target& t, uint16_t address, int count, std::string& why) {
  Bytes req = read_request(3, address, uint16_t(count));
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
  if (!j.ok() || j.registers.size() != size_t(count)) {
    why = j.problems.empty() ? "malformed reply" : j.problems.front();
    return std::nullopt;
  }
  return j.registers;
}

// Writes `values` at `address`: FC 06 for one word when the profile has it,
// else FC 16 (a 2-word value is written whole, never split in two FC 06).
bool write_words(Target& t, const spec::Spec& s, uint16_t address, std::span<const uint16_t> values, std::string& why) {
  bool fc06 = s.profile.function(6) != nullptr, fc16 = s.profile.function(16) != nullptr;
  Bytes req;
  if (values.size() == 1 && (fc06 || !fc16))
    req = write_single_register(address, values[0]);
  else if (fc16)
    req = write_multiple_registers(address, values);
  else {
    why = "the profile has no FC 16 to write a 2-word value whole";
    return false;
  }
  Reply r = t.transact(req);
  if (!r.pdu) {
    why = r.silent() ? "no reply" : r.framing_error;
    return false;
  }
  Judged j = judge_reply(req, *r.pdu);
  if (j.kind == Judged::Kind::exception) {
    why = fmt::format("exception {:02X}", j.exception_code);
    return false;
  }
  if (!j.ok()) {
    why = j.problems.empty() ? "malformed reply" : j.problems.front();
    return false;
  }
  return true;
}

// Writes and reads back; the failure message, empty on success.
std::string write_verified(Target& t, const spec::Spec& s, uint16_t address, std::span<const uint16_t> values,
                           const std::string& what) {
  std::string why;
  if (!write_words(t, s, address, values, why)) return fmt::format("{}: write failed: {}", what, why);
  auto back = read_words(t, address, int(values.size()), why);
  if (!back) return fmt::format("{}: read-back failed: {}", what, why);
  if (!std::equal(back->begin(), back->end(), values.begin(), values.end()))
    return fmt::format("{}: wrote {:04X}, reads back {:04X}", what, fmt::join(values, " "), fmt::join(*back, " "));
  return "";
}

}  // namespace

WriteDecision may_write(const spec::Spec& s, const Register& r, const TargetInfo& target, const WritePolicy& p) {
  if (!target.live) return {};
  if (r.access == Access::command || r.command) {
    // A command starts motion, homes, resets or saves: never on a live drive by default.
    if (r.command && r.command->motion && !p.allow_motion)
      return {false, fmt::format("{}: motion command register: needs --allow-motion", reg_name(r))};
    if (!p.allow_motion)
      return {false, fmt::format("{}: command register: needs --allow-motion", reg_name(r))};
    if (r.command && r.command->eeprom && !p.allow_eeprom_writes)
      return {false, fmt::format("{}: command stores to EEPROM: needs --allow-eeprom-writes", reg_name(r))};
    return {};
  }
  const auto& ps = r.persistence;
  if (ps.store != spec::Store::none && ps.by == spec::PersistBy::on_write && !p.allow_eeprom_writes) {
    if (ps.unless_register) return {};  // the run turns the "do not persist" switch on first (Snapshot::take)
    return {false, fmt::format("{}: stored to {} on every write: needs --allow-eeprom-writes", reg_name(r),
                               ps.store == spec::Store::flash ? "flash" : "EEPROM")};
  }
  return {};
}

Snapshot Snapshot::take(Target& t, const spec::Spec& s, const WritePolicy& policy) {
  Snapshot snap;
  snap.spec_ = &s;
  auto sw = persist_switch_of(s);
  for (const auto& r : s.registers) {
    if (r.table != Table::holding || r.access != Access::rw || r.command) continue;
    if (sw && r.address == sw->first) continue;  // kept apart, restored last
    if (!may_write(s, r, t.info(), policy).allowed) continue;
    snap.kept_.push_back({r.address, r.words, {0, 0}, reg_name(r)});
  }
  if (!s.profile.function(3)) {
    snap.failures_.push_back("the profile has no FC 03: nothing can be read back");
    snap.kept_.clear();
    return snap;
  }
  // Read runs of adjacent registers in chunks; a chunk that fails is read
  // register by register so one bad address does not hide the rest.
  const int max_read = max_quantity(s, 3, kStandardMaxRead);
  std::vector<Kept> read_ok;
  for (size_t i = 0; i < snap.kept_.size();) {
    size_t j = i;
    int words = snap.kept_[i].words;
    while (j + 1 < snap.kept_.size() && snap.kept_[j + 1].address == snap.kept_[j].address + snap.kept_[j].words &&
           words + snap.kept_[j + 1].words <= max_read) {
      ++j;
      words += snap.kept_[j].words;
    }
    std::string why;
    auto got = words <= max_read ? read_words(t, snap.kept_[i].address, words, why) : std::nullopt;
    for (size_t k = i, at = 0; k <= j; ++k) {
      Kept kept = snap.kept_[k];
      std::optional<std::vector<uint16_t>> one;
      if (got)
        one = std::vector<uint16_t>(got->begin() + ptrdiff_t(at), got->begin() + ptrdiff_t(at + size_t(kept.words)));
      else
        one = read_words(t, kept.address, kept.words, why);
      at += size_t(kept.words);
      if (!one) {
        snap.failures_.push_back(fmt::format("{}: cannot read: {}", kept.name, why));
        continue;
      }
      std::copy(one->begin(), one->end(), kept.value);
      read_ok.push_back(kept);
    }
    i = j + 1;
  }
  snap.kept_ = std::move(read_ok);

  // The switch goes on only on a live device: a reference device's
  // persistence is itself under test.
  if (sw && t.info().live && !snap.kept_.empty()) {
    std::string why;
    auto old = read_words(t, sw->first, 1, why);
    if (!old) {
      snap.failures_.push_back(fmt::format("do-not-persist switch 0x{:04X}: cannot read: {}", sw->first, why));
    } else {
      snap.switch_ = std::pair{sw->first, (*old)[0]};
      uint16_t on = uint16_t(sw->second);
      if (old->front() != on) {
        std::string err = write_verified(t, s, sw->first, std::span(&on, 1), fmt::format("do-not-persist switch 0x{:04X}", sw->first));
        if (!err.empty()) snap.failures_.push_back(err);
      }
    }
  }
  return snap;
}

std::vector<std::string> Snapshot::restore(Target& t) const {
  std::vector<std::string> failed;
  if (!spec_) return failed;
  for (const auto& k : kept_) {
    std::span<const uint16_t> want(k.value, size_t(k.words));
    std::string why;
    auto now = read_words(t, k.address, k.words, why);
    if (now && std::equal(now->begin(), now->end(), want.begin(), want.end())) continue;
    std::string err = write_verified(t, *spec_, k.address, want, k.name);
    if (!err.empty()) failed.push_back(err);
  }
  if (switch_) {  // last: until now every restoring write stayed out of EEPROM
    std::string why;
    auto now = read_words(t, switch_->first, 1, why);
    if (!now || now->front() != switch_->second) {
      std::string err = write_verified(t, *spec_, switch_->first, std::span(&switch_->second, 1),
                                       fmt::format("do-not-persist switch 0x{:04X}", switch_->first));
      if (!err.empty()) failed.push_back(err);
    }
  }
  return failed;
}

}  // namespace mbc::conf
