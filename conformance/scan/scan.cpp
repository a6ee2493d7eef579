#include "scan/scan.h"

#include <fmt/core.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <set>

#include "modbus/pdu.h"
#include "session/identity.h"
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

class Scanner {
 public:
  Scanner(const Options& o, const std::vector<const spec::Spec*>& specs) : o_(o), specs_(specs), start_(Clock::now()) {}

  Result run() {
    result_.uri = o_.uri;
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
      std::error_code ec;  // a pty, or a symlink to one (serve --pty PATH)
      if (std::filesystem::canonical(u.path, ec).string().rfind("/dev/pts/", 0) == 0)
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
      auto readable = identity_registers(*sp);
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
      // The one identity reading (session/identity.h), through this session's policy.
      const IdentityAsk asker = [&](const Bytes& pdu, std::string& error) {
        auto r = ask(session, f.unit, pdu, at);
        if (!r) error = "held back by the frame policy";
        return r;
      };
      Identity id = read_identity(*sp, asker, IdentityOptions{16, 1, true, true});
      if (id.by_fc43 && !id.objects.empty()) {
        const auto& want = sp->device.identification;
        const bool same = id.objects[0] == want.vendor_name && id.objects[1] == want.product_code;
        m.score = same ? 1.0 : 0.0;
        m.evidence = fmt::format("FC 43/14 VendorName \"{}\", ProductCode \"{}\"{}", id.objects[0], id.objects[1],
                                 same ? "" : fmt::format(" (the spec says \"{}\", \"{}\")", want.vendor_name, want.product_code));
      } else {
        // No identification objects: the registers the spec states readable.
        if (id.by_fc43) id = read_identity(*sp, asker, IdentityOptions{16, 1, false, true});
        if (id.reads.empty()) continue;
        // A register matches when it is answered and, where the spec states
        // its range, holds a value inside it: two drives that both answer
        // the same addresses are told apart by what they hold there.
        size_t read = 0;
        for (const IdentityRead& got : id.reads) {
          if (got.kind != IdentityRead::Kind::answered) continue;
          const spec::Register& r = *got.reg;
          if (r.words == 1 && r.range && r.basis_of(spec::Fact::range).basis == spec::Basis::stated &&
              r.type != spec::DataType::f32) {
            const uint16_t w = *got.word();
            const double v = r.is_signed() ? double(int16_t(w)) : double(w);
            if (v < r.range->min || v > r.range->max) continue;
          }
          ++read;
        }
        m.score = double(read) / double(id.reads.size());
        m.evidence = fmt::format("{} of {} registers the spec states readable read, in their stated ranges", read, id.reads.size());
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
    f.target = u.scheme == "rtu" ? fmt::format("rtu://{}?{}&unit={}", u.path, f.setting->query(), f.unit)
                                 : fmt::format("{}://{}:{}?unit={}", u.scheme, u.host, u.port, f.unit);
    f.command = f.best ? fmt::format("mbconform run --target '{}' --device {} --plan", f.target, f.best->spec_id)
                       : fmt::format("mbconform run --target '{}' --map auto --plan", f.target);
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
  for (const auto& t : r.tried) out += fmt::format("tried {}\n", t);
  for (const auto& n : r.notes) out += fmt::format("note: {}\n", n);
  return out;
}

std::string to_json(const Result& r) {
  nlohmann::json j;
  j["uri"] = r.uri;
  j["requests"] = r.requests;
  j["seconds"] = r.seconds;
  j["partial"] = r.partial;
  if (r.partial) j["partial_why"] = r.partial_why;
  j["tried"] = r.tried;
  j["notes"] = r.notes;
  j["units"] = nlohmann::json::array();
  for (const Found& f : r.units) {
    nlohmann::json u{{"unit", f.unit}, {"answered", f.answered}, {"confidence", f.confidence}, {"target", f.target},
                     {"command", f.command}};
    if (f.setting)
      u["settings"] = {{"baud", f.setting->baud}, {"data", f.setting->data_bits}, {"parity", std::string(1, f.setting->parity)},
                       {"stop", f.setting->stop_bits}};
    if (f.best) u["spec"] = {{"id", f.best->spec_id}, {"score", f.best->score}, {"evidence", f.best->evidence}};
    for (const Match& m : f.others) u["others"].push_back({{"id", m.spec_id}, {"score", m.score}, {"evidence", m.evidence}});
    j["units"].push_back(u);
  }
  return j.dump(2) + "\n";
}

Result from_json(const std::string& text, const std::string& what) {
  auto bad = [&](const std::string& why) { return std::invalid_argument(fmt::format("{}: not a scan file (mbconform scan ... --out FILE): {}", what, why)); };
  nlohmann::json j = nlohmann::json::parse(text, nullptr, false);
  if (j.is_discarded() || !j.is_object()) throw bad("not a JSON object");
  if (!j.contains("uri") || !j["uri"].is_string()) throw bad("no \"uri\" (the line scanned)");
  if (!j.contains("units") || !j["units"].is_array()) throw bad("no \"units\" list");
  Result r;
  r.uri = j["uri"].get<std::string>();
  Uri line;
  try {
    line = parse_uri(r.uri);
  } catch (const std::exception& e) {
    throw bad(fmt::format("\"uri\": {}", e.what()));
  }
  if (line.scheme != "rtu" && line.scheme != "tcp" && line.scheme != "rtu-tcp")
    throw bad(fmt::format("\"uri\" '{}': not a serial line or a gateway", r.uri));
  r.partial = j.value("partial", false);
  r.partial_why = j.value("partial_why", std::string());
  if (j.contains("tried") && j["tried"].is_array())
    for (const auto& t : j["tried"]) if (t.is_string()) r.tried.push_back(t.get<std::string>());
  if (j.contains("notes") && j["notes"].is_array())
    for (const auto& n : j["notes"]) if (n.is_string()) r.notes.push_back(n.get<std::string>());
  std::set<int> seen;
  for (const auto& u : j["units"]) {
    if (!u.is_object() || !u.contains("unit") || !u["unit"].is_number_integer()) throw bad("a unit without a \"unit\" number");
    const int unit = u["unit"].get<int>();
    if (unit < 1 || unit > 247) throw bad(fmt::format("unit {}: outside 1-247", unit));
    if (!seen.insert(unit).second) throw bad(fmt::format("unit {} listed twice", unit));
    Found f;
    f.unit = uint8_t(unit);
    f.answered = u.value("answered", std::string());
    f.confidence = u.value("confidence", std::string("none"));
    f.command = u.value("command", std::string());
    f.target = u.value("target", std::string());
    // The target must be this unit on this line: a hand-edited file never
    // sends a drive's cases to another port or another unit.
    Uri t;
    try {
      t = parse_uri(f.target);
    } catch (const std::exception& e) {
      throw bad(fmt::format("unit {}: \"target\": {}", unit, e.what()));
    }
    if (t.scheme != line.scheme || t.path != line.path || t.host != line.host || t.port != line.port ||
        t.param("unit") != std::to_string(unit))
      throw bad(fmt::format("unit {}: its target '{}' is not unit {} on {}", unit, f.target, unit, r.uri));
    if (u.contains("settings") && u["settings"].is_object()) {
      const auto& s = u["settings"];
      const std::string p = s.value("parity", std::string("E"));
      f.setting = Setting{s.value("baud", 19200), s.value("data", 8), p.empty() ? 'E' : p[0], s.value("stop", 1)};
    }
    if (u.contains("spec") && u["spec"].is_object()) {
      const auto& m = u["spec"];
      if (!m.contains("id") || !m["id"].is_string() || m["id"].get<std::string>().empty()) throw bad(fmt::format("unit {}: a spec with no id", unit));
      f.best = Match{m["id"].get<std::string>(), m.value("score", 0.0), m.value("evidence", std::string())};
    }
    r.units.push_back(std::move(f));
  }
  return r;
}

std::pair<int, int> parse_units(const std::string& text) {
  auto number = [&](const std::string& t) {
    if (t.empty() || t.size() > 3 || t.find_first_not_of("0123456789") != std::string::npos) return -1;
    return std::atoi(t.c_str());
  };
  int first = -1, last = -1;
  if (auto dash = text.find('-'); dash != std::string::npos) {
    first = number(text.substr(0, dash));
    last = number(text.substr(dash + 1));
  } else {
    first = last = number(text);
  }
  if (first < 1 || last > 247 || first > last)
    throw std::invalid_argument(fmt::format("'{}': expected FIRST-LAST within 1-247", text));
  return {first, last};
}

std::string line_of(const std::string& uri) {
  Uri u = parse_uri(uri);
  return u.scheme == "rtu" ? u.path : fmt::format("{}:{}", u.host, u.port);
}

}  // namespace mbc::conf::scan
