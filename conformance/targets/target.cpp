#include "targets/target.h"

#include <fmt/core.h>

#include <charconv>
#include <stdexcept>

#include "modbus/crc16.h"
#include "modbus/rtu.h"
#include "modbus/limits.h"
#include "targets/kinds.h"

namespace mbc::conf {

std::vector<Reply> Target::transact_all(std::span<const Request> requests, size_t) {
  std::vector<Reply> out;
  out.reserve(requests.size());
  for (const auto& r : requests) out.push_back(transact(r.unit, r.pdu));
  return out;
}

std::optional<std::string> Uri::param(const std::string& key) const {
  for (const auto& [k, v] : query)
    if (k == key) return v;
  return std::nullopt;
}

Uri parse_uri(const std::string& text) {
  Uri u;
  auto colon = text.find(':');
  if (colon == std::string::npos || colon == 0)
    throw std::invalid_argument(fmt::format("target '{}': expected SCHEME:..., e.g. ref:hsc60 or tcp://127.0.0.1:502", text));
  u.scheme = text.substr(0, colon);
  std::string rest = text.substr(colon + 1);
  auto q = rest.find('?');
  std::string query = q == std::string::npos ? "" : rest.substr(q + 1);
  rest = rest.substr(0, q);
  if (rest.rfind("//", 0) == 0) {
    rest = rest.substr(2);
    auto slash = rest.find('/');
    std::string authority = rest.substr(0, slash);
    u.path = slash == std::string::npos ? "" : rest.substr(slash);
    if (!authority.empty()) {
      std::string host = authority, port;
      if (authority.front() == '[') {
        auto close = authority.find(']');
        if (close == std::string::npos) throw std::invalid_argument(fmt::format("target '{}': unclosed '['", text));
        host = authority.substr(1, close - 1);
        if (close + 1 < authority.size() && authority[close + 1] == ':') port = authority.substr(close + 2);
      } else if (auto c = authority.rfind(':'); c != std::string::npos) {
        host = authority.substr(0, c);
        port = authority.substr(c + 1);
      }
      u.host = host;
      if (!port.empty()) {
        unsigned p = 0;
        auto [end, ec] = std::from_chars(port.data(), port.data() + port.size(), p);
        if (ec != std::errc{} || end != port.data() + port.size() || p == 0 || p > 65535)
          throw std::invalid_argument(fmt::format("target '{}': bad port '{}'", text, port));
        u.port = uint16_t(p);
      }
    }
  } else {
    u.path = rest;
  }
  size_t at = 0;
  while (at < query.size()) {
    auto amp = query.find('&', at);
    std::string kv = query.substr(at, amp == std::string::npos ? std::string::npos : amp - at);
    at = amp == std::string::npos ? query.size() : amp + 1;
    if (kv.empty()) continue;
    auto eq = kv.find('=');
    std::string key = kv.substr(0, eq);
    // One value per parameter: "unit=1&unit=2" must not pass as either.
    if (u.param(key)) throw std::invalid_argument(fmt::format("target '{}': parameter '{}' given twice", text, key));
    u.query.emplace_back(key, eq == std::string::npos ? "" : kv.substr(eq + 1));
  }
  // rtu://dev/ttyUSB0 reads as host "dev": the device path follows three slashes.
  if (u.scheme == "rtu" && !u.host.empty())
    throw std::invalid_argument(fmt::format("target '{}': a serial line is rtu:///PATH (three slashes), e.g. rtu:///dev/ttyUSB0; "
                                            "'{}' is not a path",
                                            text, text.substr(0, text.find('?'))));
  return u;
}

const char* to_string(TargetKind k) {
  switch (k) {
    case TargetKind::ref: return "ref";
    case TargetKind::tcp: return "tcp";
    case TargetKind::rtu_tcp: return "rtu-tcp";
    case TargetKind::rtu: return "rtu";
    case TargetKind::tls: return "tls";
    case TargetKind::plugin: return "plugin";
  }
  return "?";
}

std::optional<TargetKind> kind_of_scheme(std::string_view scheme) {
  if (scheme == "ref") return TargetKind::ref;
  if (scheme == "tcp") return TargetKind::tcp;
  if (scheme == "rtu-tcp") return TargetKind::rtu_tcp;
  if (scheme == "rtu") return TargetKind::rtu;
  if (scheme == "mbtls") return TargetKind::tls;
  if (scheme == "plugin") return TargetKind::plugin;
  return std::nullopt;
}

TargetKind kind_of_uri(const Uri& u, const std::string& text) {
  auto kind = kind_of_scheme(u.scheme);
  if (!kind)
    throw std::invalid_argument(
        fmt::format("target '{}': unknown scheme '{}' (ref, tcp, rtu-tcp, rtu, plugin, mbtls)", text, u.scheme));
  return *kind;
}

// TCP and TLS carry MBAP; the others RTU frames (rtu-tcp: RTU over a socket,
// ref and plugin: in process, RTU framed).
Framing framing_of(TargetKind k) { return k == TargetKind::tcp || k == TargetKind::tls ? &mbc::kTcp : &mbc::kRtu; }

// A socket or a serial line reaches a device nobody here wrote; ref and a
// plugin run in this process.
bool is_live(TargetKind k) { return k != TargetKind::ref && k != TargetKind::plugin; }

std::unique_ptr<Target> open_target(const std::string& text) {
  Uri u = parse_uri(text);
  switch (kind_of_uri(u, text)) {
    case TargetKind::ref: return make_ref_target(u);
    case TargetKind::tcp:
    case TargetKind::rtu_tcp:
    case TargetKind::rtu: return make_modbus_target(u);
    case TargetKind::plugin: return make_plugin_target(u);
    case TargetKind::tls: return make_tls_target(u);
  }
  return nullptr;
}

void decode_rtu_reply(Reply& r, uint8_t slave) {
  r.pdu.reset();
  r.framing_error.clear();
  if (r.frame.empty()) return;
  // Address, PDU, CRC (MB-SL v1.02 §2.5.1): modbus/rtu.h unframes it.
  Unframed u = rtu_unframe(r.frame);
  if (!u.ok()) r.framing_error = "reply: " + u.error;
  else if (u.unit != slave) r.framing_error = fmt::format("reply from slave {}, request went to {}", u.unit, slave);
  else r.pdu = std::move(u.pdu);
}

}  // namespace mbc::conf
