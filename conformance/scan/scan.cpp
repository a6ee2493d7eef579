#include "scan/scan.h"

#include <fmt/core.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <map>
#include <nlohmann/json.hpp>
#include <set>

#include "modbus/pdu.h"
#include "session/session.h"

namespace mbc::conf::scan {
namespace {

using Clock = std::chrono::steady_clock;

// The baud rates and formats drives ship with, most common first.
constexpr int kCommonBauds[] = {19200, 9600, 38400, 57600, 115200, 4800, 2400};
constexpr const char* kCommonFormats[] = {"8E1", "8N1", "8O1", "8N2"};

std::optional<Setting> setting_of(int baud, const std::string& format) {
  if (format.size() != 3 || format[0] < '5' || format[0] > '8') return std::nullopt;
  char p = char(std::toupper(static_cast<unsigned char>(format[1])));
  if (p != 'N' && p != 'E' && p != 'O') return std::nullopt;
  if (format[2] != '1' && format[2] != '2') return std::nullopt;
  return Setting{baud, format[0] - '0', p, format[2] - '0'};
}

bool answers_fc43_14(const spec::Spec& s) {
  const auto* f = s.profile.function(43);
  return f && std::find(f->mei_types.begin(), f->mei_types.end(), 14) != f->mei_types.end() &&
         !s.device.identification.product_code.empty();
}

// Registers whose readability the spec states, holding or input, in a table the profile reads.
std::vector<const spec::Register*> stated_readable(const spec::Spec& s) {
  std::vector<const spec::Register*> out;
  for (const auto& r : s.registers) {
    if (r.table != spec::Table::holding && r.table != spec::Table::input) continue;
    if (r.access == spec::Access::wo || r.access == spec::Access::command) continue;
    if (r.basis_of(spec::Fact::read).basis != spec::Basis::stated) continue;
    if (!s.profile.function(r.table == spec::Table::holding ? 3 : 4)) continue;
    out.push_back(&r);
  }
  return out;
}

class Scanner {
 public:
  Scanner(const Options& o, const std::vector<const spec::Spec*>& specs) : o_(o), specs_(specs), start_(Clock::now()) {}

  Result run() {
    Uri u = parse_uri(o_.uri);
    if (u.scheme != "rtu" && u.scheme != "tcp" && u.scheme != "rtu-tcp")
      throw std::invalid_argument("scan: '" + o_.uri + "': expected rtu:///dev/..., tcp://HOST:PORT or rtu-tcp://HOST:PORT");
    if (u.param("unit")) throw std::invalid_argument("scan: the URI names a unit: scan looks for them (--units narrows)");
    const std::string base = u.scheme == "rtu" ? "rtu://" + u.path : fmt::format("{}://{}:{}", u.scheme, u.host, u.port);
    std::string extra;  // timeout and silence, as the user gave them
    for (const auto& [k, v] : u.query)
      if (k != "baud" && k != "parity" && k != "data" && k != "stop") extra += fmt::format("&{}={}", k, v);
    if (!u.param("timeout")) extra += fmt::format("&timeout={}", o_.timeout.count());
    if (u.scheme != "rtu") {
      sweep(base + "?unit=" + std::to_string(o_.first_unit) + extra, std::nullopt);
    } else {
      Given g;
      if (auto b = u.param("baud")) g.baud = std::atoi(b->c_str());
      if (auto p = u.param("parity"); p && !p->empty()) g.parity = char(std::toupper(static_cast<unsigned char>((*p)[0])));
      if (auto d = u.param("data")) g.data_bits = std::atoi(d->c_str());
      if (auto s = u.param("stop")) g.stop_bits = std::atoi(s->c_str());
      for (const Setting& s : candidate_settings(specs_, g)) {
        if (result_.partial) break;
        size_t before = result_.units.size();
        sweep(fmt::format("{}?{}&unit={}{}", base, s.query(), o_.first_unit, extra), s);
        if (result_.units.size() > before && !o_.all_settings) break;
      }
      if (u.path.rfind("/dev/pts/", 0) == 0 || u.path.rfind("/tmp/", 0) == 0)
        result_.notes.push_back("a pseudo-terminal carries the baud rate but not parity or stop bits: on a pty the "
                                "format found is the first tried at that rate");
    }
    result_.seconds = std::chrono::duration<double>(Clock::now() - start_).count();
    return std::move(result_);
  }

 private:
  bool out_of_budget(const std::string& at) {
    if (Clock::now() - start_ < o_.budget) return false;
    result_.partial = true;
    result_.partial_why = fmt::format("the budget of {} s ran out at {}", o_.budget.count() / 1000.0, at);
    return true;
  }

  // Sends one read-only request; nullopt when the policy held it back.
  std::optional<Reply> ask(Session& s, uint8_t unit, const Bytes& pdu, const std::string& at) {
    Sent sent = s.transact(unit, pdu, Target::Wait::reply);
    ++result_.requests;
    if (o_.on_probe) o_.on_probe(result_.requests, at);
    if (sent.refused) return std::nullopt;
    if (sent.lost) throw std::runtime_error("the line was lost: " + sent.reply.framing_error);
    return sent.reply;
  }

  void sweep(const std::string& uri, const std::optional<Setting>& setting) {
    SessionOptions so;
    so.command = "scan";
    Session session(uri, nullptr, so);
    const std::string label = setting ? setting->text() : "units";
    size_t found = 0, garbled = 0;
    // The probes: a read of one holding register at 0, then at the first
    // address each known spec states is readable (a drive that is silent
    // where it maps nothing still answers there). At most four.
    std::vector<Bytes> probes{read_request(3, 0, 1)};
    for (const spec::Spec* sp : specs_) {
      auto readable = stated_readable(*sp);
      if (readable.empty() || probes.size() >= 4) continue;
      const auto* r = readable.front();
      Bytes p = read_request(r->table == spec::Table::holding ? 3 : 4, r->address, 1);
      if (std::find(probes.begin(), probes.end(), p) == probes.end()) probes.push_back(p);
    }
    try {
      for (int unit = o_.first_unit; unit <= o_.last_unit; ++unit) {
        const std::string at = fmt::format("{} unit {}", label, unit);
        if (out_of_budget(at)) break;
        session.check_running();
        std::optional<Reply> got;
        for (const Bytes& p : probes) {
          auto r = ask(session, uint8_t(unit), p, at);
          if (!r) continue;
          if (r->pdu) {
            got = r;
            break;
          }
          if (!r->silent()) ++garbled;
        }
        if (!got) continue;
        ++found;
        Found f;
        f.unit = uint8_t(unit);
        f.setting = setting;
        const Bytes& pdu = *got->pdu;
        f.answered = pdu.size() >= 2 && (pdu[0] & 0x80) ? fmt::format("exception {:02X}", pdu[1]) : "normal reply";
        identify(session, f, at);
        result_.units.push_back(std::move(f));
      }
    } catch (const Stopped& e) {
      result_.partial = true;
      result_.partial_why = e.what();
    }
    result_.tried.push_back(fmt::format("{}: {}{}", label, found ? fmt::format("{} unit(s)", found) : "nothing",
                                        garbled ? fmt::format(", {} frames that did not decode (another setting?)", garbled) : ""));
  }

  void identify(Session& session, Found& f, const std::string& at) {
    std::vector<Match> matches;
    for (const spec::Spec* sp : specs_) {
      if (sp->device.id == "modbus-standard") continue;  // describes any server: identifies nothing
      Match m{sp->device.id, 0, ""};
      bool decided = false;
      if (answers_fc43_14(*sp)) {
        if (auto r = ask(session, f.unit, read_device_identification(1, 0), at)) {
          auto objects = r->pdu ? device_identification(*r->pdu) : std::map<int, std::string>{};
          if (!objects.empty()) {
            const auto& id = sp->device.identification;
            bool same = objects[0] == id.vendor_name && objects[1] == id.product_code;
            m.score = same ? 1.0 : 0.0;
            m.evidence = fmt::format("FC 43/14 VendorName \"{}\", ProductCode \"{}\"{}", objects[0], objects[1],
                                     same ? "" : fmt::format(" (the spec says \"{}\", \"{}\")", id.vendor_name, id.product_code));
            decided = true;
          }
        }
      }
      if (!decided) {
        auto readable = stated_readable(*sp);
        if (readable.empty()) continue;
        // A register matches when it is answered and, where the spec states
        // its range, holds a value inside it: two drives that both answer
        // the same addresses are told apart by what they hold there.
        const size_t samples = std::min<size_t>(16, readable.size());
        size_t read = 0;
        for (size_t k = 0; k < samples; ++k) {
          const spec::Register& r = *readable[k * readable.size() / samples];
          const uint8_t fc = r.table == spec::Table::holding ? 3 : 4;
          auto got = ask(session, f.unit, read_request(fc, r.address, uint16_t(r.words)), at);
          if (!got || !got->pdu || got->pdu->size() != size_t(2 + 2 * r.words) || (*got->pdu)[0] != fc) continue;
          if (r.words == 1 && r.range && r.basis_of(spec::Fact::range).basis == spec::Basis::stated &&
              r.type != spec::DataType::f32) {
            const uint16_t w = uint16_t((*got->pdu)[2] << 8 | (*got->pdu)[3]);
            const double v = r.is_signed() ? double(int16_t(w)) : double(w);
            if (v < r.range->min || v > r.range->max) continue;
          }
          ++read;
        }
        m.score = double(read) / double(samples);
        m.evidence = fmt::format("{} of {} registers the spec states readable read, in their stated ranges", read, samples);
      }
      // The spec's own line settings agreeing is a small point more.
      if (f.setting && sp->serial.baud_default == f.setting->baud) m.score = std::min(1.0, m.score + 0.01);
      matches.push_back(m);
    }
    std::stable_sort(matches.begin(), matches.end(), [](const Match& a, const Match& b) { return a.score > b.score; });
    const double second = matches.size() > 1 ? matches[1].score : 0;
    if (!matches.empty() && matches[0].score >= 0.5) {
      f.best = matches[0];
      const double margin = matches[0].score - second;
      f.confidence = matches[0].score >= 0.99 && margin >= 0.25   ? "high"
                     : matches[0].score >= 0.74 && margin >= 0.12 ? "medium"
                                                                  : "low";
      matches.erase(matches.begin());
    } else {
      f.confidence = "none";
    }
    f.others = std::move(matches);
    Uri u = parse_uri(o_.uri);
    std::string target = u.scheme == "rtu" ? fmt::format("rtu://{}?{}&unit={}", u.path, f.setting->query(), f.unit)
                                           : fmt::format("{}://{}:{}?unit={}", u.scheme, u.host, u.port, f.unit);
    f.command = f.best ? fmt::format("mbconform run --target '{}' --device {} --plan", target, f.best->spec_id)
                       : fmt::format("mbconform run --target '{}' --map auto --plan", target);
  }

  const Options& o_;
  const std::vector<const spec::Spec*>& specs_;
  Clock::time_point start_;
  Result result_;
};

}  // namespace

std::string Setting::text() const { return fmt::format("{} {}{}{}", baud, data_bits, parity, stop_bits); }
std::string Setting::query() const { return fmt::format("baud={}&parity={}&data={}&stop={}", baud, parity, data_bits, stop_bits); }

std::vector<Setting> candidate_settings(const std::vector<const spec::Spec*>& specs, const Given& given) {
  std::vector<Setting> out;
  auto add = [&](std::optional<Setting> s) {
    if (!s) return;
    if (given.baud && s->baud != *given.baud) return;
    if (given.parity && s->parity != *given.parity) return;
    if (given.data_bits && s->data_bits != *given.data_bits) return;
    if (given.stop_bits && s->stop_bits != *given.stop_bits) return;
    if (std::find(out.begin(), out.end(), *s) == out.end()) out.push_back(*s);
  };
  // The known specs' own defaults first (MB-SL v1.02 §2.5.1's 19200 8E1 where a spec states none).
  for (const spec::Spec* s : specs)
    if (s->device.id != "modbus-standard")
      add(setting_of(s->serial.baud_default.value_or(19200), s->serial.frame_default.value_or("8E1")));
  for (int b : kCommonBauds)
    for (const char* f : kCommonFormats) add(setting_of(b, f));
  for (const spec::Spec* s : specs)
    for (int b : s->serial.baud_rates)
      for (const auto& f : s->serial.frame_formats) add(setting_of(b, f));
  // A rate or format the URI gives that nothing above has.
  if (given.baud && out.empty())
    for (const char* f : kCommonFormats) add(setting_of(*given.baud, f));
  if (given.baud && given.parity && out.empty())
    out.push_back(Setting{*given.baud, given.data_bits.value_or(8), *given.parity, given.stop_bits.value_or(1)});
  return out;
}

Result scan(const Options& options, const std::vector<const spec::Spec*>& specs) {
  if (options.first_unit < 1 || options.last_unit > 247 || options.first_unit > options.last_unit)
    throw std::invalid_argument("scan: units must be within 1-247");
  return Scanner(options, specs).run();
}

std::string table(const Result& r) {
  std::string out = fmt::format("{:<5} {:<10} {:<16} {:<24} {:<10} {}\n", "unit", "settings", "answered", "spec", "confidence", "evidence");
  for (const Found& f : r.units)
    out += fmt::format("{:<5} {:<10} {:<16} {:<24} {:<10} {}\n", f.unit, f.setting ? f.setting->text() : "-", f.answered,
                       f.best ? f.best->spec_id : "(none known)", f.confidence, f.best ? f.best->evidence : "");
  if (!r.units.empty()) out += "\nto qualify each (--plan lists every frame first; drop it to run):\n";
  for (const Found& f : r.units) out += fmt::format("  {}\n", f.command);
  return out;
}

std::string to_json(const Result& r, const std::string& uri) {
  nlohmann::json j;
  j["uri"] = uri;
  j["requests"] = r.requests;
  j["seconds"] = r.seconds;
  j["partial"] = r.partial;
  if (r.partial) j["partial_why"] = r.partial_why;
  j["tried"] = r.tried;
  j["notes"] = r.notes;
  j["units"] = nlohmann::json::array();
  for (const Found& f : r.units) {
    nlohmann::json u{{"unit", f.unit}, {"answered", f.answered}, {"confidence", f.confidence}, {"command", f.command}};
    if (f.setting)
      u["settings"] = {{"baud", f.setting->baud}, {"data", f.setting->data_bits}, {"parity", std::string(1, f.setting->parity)},
                       {"stop", f.setting->stop_bits}};
    if (f.best) u["spec"] = {{"id", f.best->spec_id}, {"score", f.best->score}, {"evidence", f.best->evidence}};
    for (const Match& m : f.others) u["others"].push_back({{"id", m.spec_id}, {"score", m.score}, {"evidence", m.evidence}});
    j["units"].push_back(u);
  }
  return j.dump(2) + "\n";
}

}  // namespace mbc::conf::scan
