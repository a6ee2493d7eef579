#include "session/session.h"

#include <fmt/core.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <ctime>
#include <map>
#include <set>
#include <tuple>
#include <thread>

#include "modbus/limits.h"
#include "modbus/pdu.h"
#include "safety/safety.h"
#include "session/identity.h"
#include "session/signals.h"
#include "report/utc_now.h"

namespace mbc::conf {
namespace {

using Clock = std::chrono::steady_clock;

// MB-SL v1.02 §2.5.1: the default line is 19200 baud, 8 data bits, even parity, 1 stop bit.
constexpr int kStandardBaud = 19200;
constexpr const char* kStandardFrame = "8E1";

// Whether the target answers at all: the first item the profile can read,
// one item, three tries with reconnects; any reply, even an exception, is
// an answer. Empty when it answers, else why not.
std::string unreachable(Target& t, const spec::Spec& s) {
  const Bytes pdu = probe_request(s);
  // Bytes that never decode as a frame of the target's framing are no answer
  // either: the framing is wrong (an RTU drive behind a tcp:// URI, a TLS
  // server without the MBAP header), and every case would fail for it.
  constexpr int kTries = 3;
  std::string why = "no reply";
  std::optional<Reply> garbled;
  for (int attempt = 0; attempt < kTries; ++attempt) {
    if (attempt > 0) t.reconnect();
    try {
      Reply got = t.transact(t.info().unit, pdu);
      if (got.pdu) return "";
      if (!got.silent()) garbled = got;
      else if (got.closed) why = "the connection was closed";
    } catch (const std::exception& e) {
      why = e.what();
    }
  }
  if (garbled)
    return fmt::format("{} answers, but never with a frame that decodes ({} tries; last: {}: {}): is the framing right?",
                       t.info().uri, kTries, to_hex(garbled->frame), garbled->framing_error.empty() ? "not a frame" : garbled->framing_error);
  return fmt::format("{} does not answer ({} tries, with reconnects; last: {})", t.info().uri, kTries, why);
}

}  // namespace

Bytes probe_request(const spec::Spec& s) {
  for (const auto& r : s.registers) {
    if (r.access == spec::Access::wo || r.access == spec::Access::command) continue;
    int fc = r.table == spec::Table::holding ? 3 : r.table == spec::Table::input ? 4 : r.table == spec::Table::coil ? 1 : 2;
    if (s.profile.function(fc)) return read_request(uint8_t(fc), r.address, 1);
  }
  return read_request(3, 0, 1);
}

// ---- line settings ---------------------------------------------------------

LineSettings line_settings(const std::string& uri, const spec::Spec* spec) {
  Uri u = parse_uri(uri);
  LineSettings ls;
  ls.uri = uri;
  if (u.scheme == "ref" || u.scheme == "plugin") return ls;
  std::vector<std::string> added;
  std::string from_spec = spec ? fmt::format("from the spec {}", spec->device.id) : "";
  std::vector<std::string> origins;
  auto add = [&](const std::string& key, const std::string& value) {
    ls.uri += fmt::format("{}{}={}", ls.uri.find('?') == std::string::npos ? "?" : "&", key, value);
  };
  std::string tried;
  if (u.scheme == "rtu") {
    std::string frame = spec && spec->serial.frame_default ? *spec->serial.frame_default : "";
    bool frame_from_spec = frame.size() == 3;
    if (!frame_from_spec) frame = kStandardFrame;
    int baud = kStandardBaud;
    std::string baud_origin;
    if (auto b = u.param("baud")) {
      baud = std::atoi(b->c_str());
      baud_origin = "from the URI";
    } else if (spec && spec->serial.baud_default) {
      baud = *spec->serial.baud_default;
      add("baud", std::to_string(baud));
      baud_origin = from_spec;
    } else {
      add("baud", std::to_string(baud));
      baud_origin = "the standard's default (MB-SL v1.02 §2.5.1)";
    }
    origins.push_back("baud " + baud_origin);
    std::string data = u.param("data").value_or(std::string(1, frame[0]));
    std::string parity = u.param("parity").value_or(std::string(1, frame[1]));
    std::string stop = u.param("stop").value_or(std::string(1, frame[2]));
    bool any_frame_given = u.param("data") || u.param("parity") || u.param("stop");
    if (!u.param("data")) add("data", data);
    if (!u.param("parity")) add("parity", parity);
    if (!u.param("stop")) add("stop", stop);
    origins.push_back("frame " + std::string(any_frame_given ? "from the URI"
                                             : frame_from_spec ? from_spec
                                                               : "the standard's default (MB-SL v1.02 §2.5.1)"));
    tried = fmt::format("{} {}{}{}", baud, data, parity, stop);
  }
  int unit = 1;
  if (auto un = u.param("unit")) {
    unit = std::atoi(un->c_str());
    origins.push_back("unit from the URI");
  } else if (spec && spec->serial.slave_default) {
    unit = *spec->serial.slave_default;
    add("unit", std::to_string(unit));
    origins.push_back("unit " + from_spec);
  } else {
    origins.push_back("unit 1 by default");
  }
  ls.tried = tried.empty() ? fmt::format("unit {}", unit) : fmt::format("{}, unit {}", tried, unit);
  ls.origin = fmt::format("{}", fmt::join(origins, ", "));
  if (spec) {
    std::string says;
    if (u.scheme == "rtu" && spec->serial.baud_default) says += std::to_string(*spec->serial.baud_default);
    if (u.scheme == "rtu" && spec->serial.frame_default) says += (says.empty() ? "" : " ") + *spec->serial.frame_default;
    if (spec->serial.slave_default) says += fmt::format("{}unit {}", says.empty() ? "" : ", ", *spec->serial.slave_default);
    if (!says.empty()) ls.spec_says = fmt::format("the spec {} says {}", spec->device.id, says);
  }
  return ls;
}

// ---- the session ------------------------------------------------------------

Session::Session(const std::string& uri, const spec::Spec* spec, SessionOptions options)
    : spec_(spec), opt_(std::move(options)) {
  line_ = line_settings(uri, spec);
  inner_ = opt_.wrap ? opt_.wrap(open_target(line_.uri)) : open_target(line_.uri);
  facts_ = PolicyFacts{spec_, inner_->info(), opt_.policy};
  if (inner_->info().live && !opt_.out_dir.empty()) {
    journal_ = Journal::create(opt_.out_dir, {{"target", inner_->info().uri},
                                              {"device", spec_ ? spec_->device.id : ""},
                                              {"spec", spec_ ? spec_->path : ""},
                                              {"spec-crc32", spec_ ? spec_fingerprint(*spec_) : ""},
                                              {"unit", std::to_string(inner_->info().unit)},
                                              {"command", opt_.command},
                                              {"started", utc_now()}});
    set_stop_journal(journal_.path());
  }
}

Session::~Session() {
  if (restored_ || !journal_.open() || journal_.kept() == 0) return;
  try {
    restore();
  } catch (...) {
  }
}

std::optional<std::string> Session::stopped() const {
  if (stop_requested()) return "stopped by " + signal_name(stop_signal());
  if (opt_.deadline && Clock::now() >= *opt_.deadline) return std::string("the time allowed ran out");
  if (!journal_.failed().empty()) return "the journal could not be written (" + journal_.failed() + ")";
  return std::nullopt;
}

void Session::check_running() const {
  if (!opt_.stop_mid_exchange && !opt_.deadline) return;
  if (auto why = stopped(); why && (opt_.stop_mid_exchange || !stop_requested())) throw Stopped(*why);
}

std::string Session::no_answer(const std::string& why) const {
  std::string s = fmt::format("{} does not answer at {} ({})", inner_->info().uri, line_.tried, line_.origin);
  if (!line_.spec_says.empty()) s += "; " + line_.spec_says;
  if (!why.empty()) s += "; last: " + why;
  return s;
}

std::string Session::reachable() {
  spec::Spec none;
  std::string why = unreachable(*inner_, spec_ ? *spec_ : none);
  if (why.empty()) return "";
  if (why.find("never with a frame that decodes") != std::string::npos)
    return fmt::format("{} (line: {}, {})", why, line_.tried, line_.origin);
  auto at = why.find("last: ");
  return no_answer(at == std::string::npos ? why : why.substr(at + 6, why.size() - at - 7));
}

std::optional<Refusal> Session::journal_range(Target& t, const WriteRange& w) {
  if (!journal_.open())
    return Refusal{"no journal (no output directory): a live target is not written without one", ""};
  // The items not journaled yet, as whole registers of the spec (a 2-word
  // value is kept and restored whole) or single items.
  struct Item {
    uint16_t address;
    int words;
    bool in_spec;
  };
  std::vector<Item> items;
  std::vector<JournalCommand> commands;
  for (int k = 0; k < w.count; ++k) {
    uint32_t a = uint32_t(w.address) + uint32_t(k);
    if (a > 0xFFFF) break;
    if (journal_.has(w.table, uint16_t(a))) continue;
    const spec::Register* r = spec_ ? spec_->register_covering(uint16_t(a), w.table) : nullptr;
    // A read-only register changes by side effect (57HS-R 0x0009, HSC60
    // 0x004B): a write to it is meant to be refused, and its value is not
    // the command's to put back.
    if (r && r->access == spec::Access::ro) continue;
    // A command register has no value to keep, and a drive may not answer
    // a read of it (issue 37): journaled as written, undone by the spec's stop.
    if (r && (r->access == spec::Access::command || r->command)) {
      if (commands.empty() || commands.back().address != r->address) commands.push_back({w.table, r->address, r->words});
      continue;
    }
    Item it{r ? r->address : uint16_t(a), r ? r->words : 1, r != nullptr};
    if (!items.empty() && items.back().address == it.address) continue;
    if (uint32_t(it.address) + uint32_t(it.words) > 0x10000) it.words = 1;
    items.push_back(it);
  }
  auto unrecorded = [&](const std::exception& e) {
    return Refusal{fmt::format("the journal could not record the value before this write ({}): not sent; the command "
                               "stops and restores", journal_.failed().empty() ? e.what() : journal_.failed()),
                   ""};
  };
  if (spec_ && spec_->control)
    for (int k = 0; k < w.count && uint32_t(w.address) + uint32_t(k) <= 0xFFFF; ++k)
      if (is_control_command_register(*spec_, w.table, uint16_t(w.address + k))) {
        try {
          record_control(t);
        } catch (const std::exception& e) {
          return unrecorded(e);
        }
        break;
      }
  if (items.empty() && commands.empty()) return std::nullopt;
  try {
    record_identity();
  } catch (const std::exception& e) {
    return unrecorded(e);
  }
  std::vector<JournalEntry> kept;
  std::vector<JournalUnread> unread;
  const int limit = journal_read_limit(spec_, w.table);
  // In runs of adjacent items within the read limit: one read each; a run
  // the drive refuses is read item by item where the spec maps the item
  // (an unmapped one it refused is not there to restore).
  for (size_t i = 0; i < items.size();) {
    size_t j = i + 1;
    int span = items[i].words;
    while (j < items.size() && items[j].address == items[j - 1].address + items[j - 1].words && span + items[j].words <= limit)
      span += items[j++].words;
    std::string why;
    auto all = read_table(t, w.table, items[i].address, span, why);
    for (size_t k = i; k < j; ++k) {
      const auto& it = items[k];
      std::optional<std::vector<uint16_t>> v;
      std::string one_why = why;
      if (all) {
        auto from = all->begin() + (it.address - items[i].address);
        v = std::vector<uint16_t>(from, from + it.words);
      } else if (j - i > 1 && it.in_spec) {
        v = read_table(t, w.table, it.address, it.words, one_why);
      }
      // A register the spec maps must read before it is written; an
      // address it does not map may get silence (a device whose policy is
      // silent there), and has nothing to put back.
      if (v) kept.push_back({w.table, it.address, *v, false, ""});
      else if (it.in_spec && no_reply(one_why))
        return Refusal{fmt::format("{}: its value could not be read before the write ({}), so it is not written",
                                   journal_label(spec_, w.table, it.address), one_why),
                       ""};
      else unread.push_back({w.table, it.address, it.words, one_why});
    }
    i = j;
  }
  try {
    journal_.keep(kept, unread, commands);
  } catch (const std::exception& e) {
    return unrecorded(e);
  }
  return std::nullopt;
}

void Session::record_control(Target& t) {
  // The control state before the command's first command write (journal `control`).
  if (!spec_ || !spec_->control || !journal_.open() || !journal_.memory().control_state.empty()) return;
  if (std::string line = control_record(t, *spec_); !line.empty()) journal_.record(line);
}

void Session::record_identity() {
  if (identity_recorded_ || !spec_ || !journal_.open()) return;
  identity_recorded_ = true;
  // Throws like keep() when the disk is full: the caller refuses the write.
  journal_.record("identity " + journal_identity(*inner_, *spec_));
}

std::optional<Refusal> Session::before_write(Target& t, uint8_t unit, std::span<const uint8_t> pdu) {
  if (Decision d = allowed(facts_, unit, pdu); !d) return d.refused;
  return journal_write(t, unit, pdu);
}

std::optional<Refusal> Session::journal_write(Target& t, uint8_t unit, std::span<const uint8_t> pdu) {
  if (!t.info().live) return std::nullopt;
  auto w = writes_of(pdu);
  if (!w || (unit != 0 && unit != t.info().unit)) return std::nullopt;
  return journal_range(t, *w);
}

std::optional<std::string> Session::stops_frames() const {
  auto why = stopped();
  if (why && (opt_.stop_mid_exchange || !stop_requested())) return why;
  return std::nullopt;
}

Sent Session::transact(uint8_t unit, std::span<const uint8_t> pdu, Target::Wait wait) {
  if (auto why = stops_frames()) {
    ++refused_;
    return Sent{{}, Refusal{*why, ""}, false, true};
  }
  if (auto r = before_write(*inner_, unit, pdu)) {
    ++refused_;
    return Sent{{}, std::move(r), false};
  }
  inner_->set_wait(wait);
  Sent sent{inner_->transact(unit, pdu), std::nullopt, false};
  count_frame();
  note_zeroed(unit, pdu, sent.reply);
  return sent;
}

std::vector<Sent> Session::transact_all(std::span<const Target::Request> requests, size_t depth, Target::Wait wait) {
  // Up to the first refusal: it is that request's, and the rest are not sent.
  auto one_by_one = [&] {
    std::vector<Sent> out;
    for (const auto& r : requests) {
      out.push_back(transact(r.unit, r.pdu, wait));
      if (out.back().refused) break;
    }
    return out;
  };
  if (!inner_->pipelines() || requests.size() < 2 || stops_frames()) return one_by_one();
  for (const auto& r : requests)
    if (Decision d = allowed(facts_, r.unit, r.pdu); !d) return one_by_one();
  for (const auto& r : requests)
    if (journal_write(*inner_, r.unit, r.pdu)) return one_by_one();
  inner_->set_wait(wait);
  std::vector<Sent> out;
  auto replies = inner_->transact_all(requests, depth);
  for (size_t k = 0; k < replies.size(); ++k) {
    count_frame();
    if (k < requests.size()) note_zeroed(requests[k].unit, requests[k].pdu, replies[k]);
    out.push_back(Sent{std::move(replies[k]), std::nullopt, false});
  }
  return out;
}

void Session::note_zeroed(uint8_t unit, std::span<const uint8_t> pdu, const Reply& reply) {
  // A write the drive echoed: which of the control's set-points it made 0
  // (the frame policy's PolicyFacts::zeroed).
  if (!spec_ || unit != inner_->info().unit || !reply.pdu || reply.pdu->empty() || ((*reply.pdu)[0] & 0x80)) return;
  mbc::conf::note_zeroed(*spec_, pdu, facts_.zeroed);
}

Sent Session::send_raw(std::span<const uint8_t> adu, std::optional<size_t> gap_after, Target::Wait wait) {
  if (auto why = stops_frames()) {
    ++refused_;
    return Sent{{}, Refusal{*why, ""}, false, true};
  }
  if (Decision d = allowed_raw(facts_, adu, gap_after); !d) {
    ++refused_;
    return Sent{{}, std::move(d.refused), false};
  }
  for (const auto& [unit, pdu] : frames_in(inner_->info().framing, adu, gap_after))
    if (auto r = journal_write(*inner_, unit, pdu)) {
      ++refused_;
      return Sent{{}, std::move(r), false};
    }
  inner_->set_wait(wait);
  Sent sent{inner_->send_raw(adu, gap_after), std::nullopt, false};
  count_frame();
  return sent;
}

void Session::restart() {
  if (auto why = stops_frames()) throw Stopped(*why);
  if (!inner_->info().live) {
    inner_ = opt_.wrap ? opt_.wrap(open_target(line_.uri)) : open_target(line_.uri);
    return;
  }
  if (!inner_->reconnect())
    throw std::runtime_error(fmt::format("the target {} cannot be opened again", inner_->info().uri));
}

std::string Session::preflight(std::string& identity) {
  // The standard's baseline describes any server that follows the
  // standard, not one product: nothing to identify.
  if (!spec_ || !inner_->info().live || spec_->device.id == "modbus-standard") return "";
  const uint8_t unit = inner_->info().unit;
  inner_->set_wait(Target::Wait::reply);
  const Identity id = read_identity(*spec_, [&](const Bytes& pdu, std::string& error) -> std::optional<Reply> {
    try {
      return inner_->transact(unit, pdu);
    } catch (const std::exception& e) {
      error = e.what();
      return std::nullopt;
    }
  });
  if (id.by_fc43) {
    const auto& want = spec_->device.identification;
    if (id.objects.empty())
      return fmt::format("--device {}: unit {} does not answer Read Device Identification (FC 43/14), which the spec says it "
                         "does: is it a {}? (--no-preflight skips this check)",
                         spec_->device.id, unit, spec_->device.id);
    identity = id.objects_text();
    const std::string vendor = id.objects.count(0) ? id.objects.at(0) : "", product = id.objects.count(1) ? id.objects.at(1) : "";
    if (vendor != want.vendor_name || product != want.product_code)
      return fmt::format("--device {}: unit {} identifies as VendorName \"{}\", ProductCode \"{}\"; the spec says \"{}\", \"{}\" "
                         "(--no-preflight skips this check)",
                         spec_->device.id, unit, vendor, product, want.vendor_name, want.product_code);
    return "";
  }
  if (id.reads.empty()) {
    identity = fmt::format("not identified: the spec {} states no FC 43/14 identity and no register as readable", spec_->device.id);
    return "";
  }
  // Only a refusal of a mapped address (exception 01 or 02) or silence
  // speaks against the identity: a reply that is malformed (a wrong byte
  // count, say) is still this drive answering, and a finding for the run.
  size_t refused = 0;
  std::vector<std::string> seen, refusals;
  for (const IdentityRead& r : id.reads) {
    const uint16_t at = r.reg->address;
    if (r.refused()) {
      ++refused;
      refusals.push_back(r.kind == IdentityRead::Kind::not_sent ? fmt::format("0x{:04X}: {}", at, r.error)
                         : r.kind == IdentityRead::Kind::silent ? fmt::format("0x{:04X}: no reply", at)
                                                                : fmt::format("0x{:04X}: exception {:02X}", at, r.exception));
    } else if (r.kind == IdentityRead::Kind::answered) {
      seen.push_back(fmt::format("0x{:04X}={:02X}", at, fmt::join(r.pdu.begin() + 2, r.pdu.end(), "")));
    } else {
      seen.push_back(fmt::format("0x{:04X} answered ({})", at,
                                 r.pdu.empty() ? std::string("a frame that does not decode") : fmt::format("{:02X}", fmt::join(r.pdu, " "))));
    }
  }
  const size_t samples = id.reads.size();
  identity = fmt::format("{} of {} registers read across the spec's map: {}", samples - refused, samples, fmt::join(seen, ", "));
  if (refused * 2 > samples)
    return fmt::format("--device {}: unit {} refuses {} of {} reads of registers the spec maps ({}): is it a {}? "
                       "(--no-preflight skips this check)",
                       spec_->device.id, unit, refused, samples, fmt::join(refusals, "; "), spec_->device.id);
  return "";
}

namespace {

// "holding 0x0010-0x001F, 0x0030 (exception 02); coils 0x0000-0x00C7 (no reply)":
// addresses grouped by table and reason, adjacent ones as ranges.
std::string ranges_line(std::vector<std::tuple<spec::Table, std::string, uint16_t, int>> items) {
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
    out += fmt::format("{}{} {} ({})", out.empty() ? "" : "; ", journal_table_name(table), list, why);
    i = j;
  }
  return out;
}

}  // namespace

void Session::keep() {
  if (!inner_->info().live || !spec_) return;
  if (!journal_.open()) throw std::runtime_error("a live target needs an output directory for its journal");
  record_identity();
  record_control(*inner_);
  // The switch first: from the moment it is on, its original is on disk.
  auto sw = persist_switch(*spec_);
  std::optional<uint16_t> switch_was;
  if (sw) {
    std::string why;
    if (auto v = read_table(*inner_, spec::Table::holding, sw->first, 1, why)) {
      journal_.keep({{spec::Table::holding, sw->first, *v, true, ""}});
      switch_was = v->front();
    } else {
      notes_.push_back(fmt::format("do-not-persist switch 0x{:04X}: cannot read: {}", sw->first, why));
    }
  }
  // Every writable register the frame policy lets this command write, read before
  // the first frame (holding registers FC 03, coils FC 01): a command that
  // ends before it restores leaves nothing unjournaled.
  std::vector<JournalEntry> wanted;
  std::vector<std::tuple<spec::Table, std::string, uint16_t, int>> unread, unwritable;
  for (const auto& r : spec_->registers) {
    if (r.access != spec::Access::rw || r.command) continue;
    if (sw && r.table == spec::Table::holding && r.address == sw->first) continue;
    if (r.table != spec::Table::holding && r.table != spec::Table::coil) {
      unwritable.emplace_back(r.table, "no Modbus function writes this table", r.address, r.words);
      continue;
    }
    if (!allowed_write(facts_, r)) continue;
    wanted.push_back({r.table, r.address, std::vector<uint16_t>(size_t(r.words), 0), false, register_label(r)});
  }
  std::vector<const JournalEntry*> ptrs;
  for (const auto& e : wanted) ptrs.push_back(&e);
  std::vector<std::string> whys;
  const auto got = read_entries(*inner_, spec_, ptrs, whys);
  std::vector<JournalEntry> kept;
  for (size_t k = 0; k < wanted.size(); ++k) {
    if (got[k]) {
      kept.push_back(wanted[k]);
      kept.back().value = *got[k];
    } else {
      unread.emplace_back(wanted[k].table, whys[k], wanted[k].address, int(wanted[k].value.size()));
    }
  }
  journal_.keep(kept);
  // One line each, with ranges: a drive that refuses 60 reads is one finding, not 60.
  if (!unread.empty()) notes_.push_back("could not be read before the run, so not restored: " + ranges_line(unread));
  if (!unwritable.empty()) notes_.push_back("marked writable but cannot be restored: " + ranges_line(unwritable));
  // 57HS-R §6.1: the switch held on keeps every write of the command out of
  // EEPROM; turning it on (and back) costs one stored write each.
  if (sw && switch_was && !kept.empty() && *switch_was != uint16_t(sw->second)) {
    const uint16_t on = uint16_t(sw->second);
    std::string err = write_table_verified(*inner_, *spec_, spec::Table::holding, sw->first, std::span(&on, 1),
                                           fmt::format("do-not-persist switch 0x{:04X}", sw->first));
    if (!err.empty()) notes_.push_back(err);
  }
}

RestoreReport Session::restore() {
  RestoreReport rep;
  rep.journal = journal_.path();
  if (!journal_.open()) {
    restored_ = true;
    return rep;
  }
  spec::Spec none;
  // The file (with what forked children journaled), and what this process
  // kept in memory: a record the disk would not take is still put back.
  JournalContents c;
  std::string unreadable;
  try {
    c = read_journal(journal_.path());
  } catch (const std::exception& e) {
    unreadable = e.what();
  }
  c = merge_journal(std::move(c), journal_.memory());
  rep = restore_journal(*inner_, spec_ ? *spec_ : none, c, journal_);
  if (rep.not_restored.empty()) forget_stop_journal(journal_.path());
  if (!unreadable.empty()) rep.notes.push_back("restored from memory: the journal file could not be read: " + unreadable);
  if (!journal_.failed().empty())
    rep.notes.push_back(fmt::format("the journal stopped recording ({}): the restore used what the command kept in memory",
                                    journal_.failed()));
  restored_ = true;
  return rep;
}

}  // namespace mbc::conf
