// A deliberately broken master, to show `mbconform client` finds exactly
// what is wrong with a master and nothing else. Without --defects it is a
// correct master (modbus/ builds the requests and judges the replies; the
// quantity limits come from modbus-standard.yaml); each defect switches off
// one check:
//   any-transaction  take a Modbus TCP reply whatever its transaction id
//   no-crc           take an RTU reply whatever its CRC
//   no-t35           send an RTU frame without t3.5 of silence before it
//   no-turnaround    go on right after an RTU broadcast, without a turnaround delay
// It speaks adapter protocol 1 (conformance/client/README.md) over real
// sockets and a real pty.
//
//   broken_master [--defects any-transaction,no-crc,no-t35,no-turnaround]
#include <fcntl.h>
#include <netdb.h>
#include <poll.h>
#include <sys/socket.h>
#include <termios.h>
#include <unistd.h>

#include <chrono>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <optional>
#include <set>
#include <string>
#include <thread>

#include <nlohmann/json.hpp>

#include "client/model.h"
#include "client/scenario.h"
#include "modbus/function_codes.h"
#include "modbus/judge.h"
#include "modbus/limits.h"
#include "modbus/mbap.h"
#include "modbus/rtu.h"

namespace {

using nlohmann::json;
using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;
using namespace mbc;

struct Defects {
  bool any_transaction = false, no_crc = false, no_t35 = false, no_turnaround = false;
};

class Master {
 public:
  explicit Master(Defects d) : defects_(d), limits_(client::standard_limits()) {}
  ~Master() { disconnect(); }

  json connect(const json& c) {
    disconnect();
    timeout_ = std::chrono::milliseconds(c.value("timeout_ms", 500));
    std::string t = c.value("transport", "");
    rtu_ = t != "tcp";
    if (t == "rtu") {
      fd_ = ::open(c.value("device", "").c_str(), O_RDWR | O_NOCTTY | O_CLOEXEC);
      if (fd_ < 0) return not_ready("open " + c.value("device", ""));
      baud_ = c.value("baud", 19200);
      termios tio{};
      tcgetattr(fd_, &tio);
      cfmakeraw(&tio);
      tcsetattr(fd_, TCSANOW, &tio);
    } else if (t == "tcp" || t == "rtu-tcp") {
      addrinfo hints{}, *res = nullptr;
      hints.ai_socktype = SOCK_STREAM;
      std::string port = std::to_string(c.value("port", 502));
      if (getaddrinfo(c.value("host", "127.0.0.1").c_str(), port.c_str(), &hints, &res) != 0) return not_ready("resolve");
      fd_ = socket(res->ai_family, SOCK_STREAM | SOCK_CLOEXEC, 0);
      int rc = fd_ < 0 ? -1 : ::connect(fd_, res->ai_addr, res->ai_addrlen);
      freeaddrinfo(res);
      if (rc != 0) return not_ready("connect");
      baud_ = 0;
    } else {
      return {{"ready", false}, {"detail", "no transport " + t}};
    }
    return {{"ready", true}};
  }

  void disconnect() {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
  }

  json request(const json& r) {
    json a{{"id", r.value("id", 0)}};
    std::string op = r.value("op", "");
    uint8_t f = client::model::function_of(op);
    if (!f) return fail(a, "unsupported");
    if (fd_ < 0) return fail(a, "other", "not connected");
    Bytes pdu = client::model::expected_request(r);
    if (pdu.size() > kMaxPdu || over_limit(r, f)) return fail(a, "refused", "over the standard's limit");
    uint8_t unit = r.value("unit", 1);
    drain();  // what arrived since the last exchange answers nothing asked now
    if (rtu_ && baud_ && !defects_.no_t35) std::this_thread::sleep_for(frame_gap(baud_));  // t3.5 before a frame
    uint16_t tid = ++transaction_;
    Bytes adu = rtu_ ? rtu_frame(unit, pdu) : mbap_frame(tid, unit, pdu);
    if (::write(fd_, adu.data(), adu.size()) != ssize_t(adu.size())) return fail(a, "other", "write failed");
    if (unit == 0 && rtu_) {  // a broadcast: no reply comes (MB-SL v1.02 §2.1); wait the turnaround delay
      if (!defects_.no_turnaround) std::this_thread::sleep_for(100ms);
      return ok(a, json::array());
    }
    auto deadline = Clock::now() + timeout_;
    for (;;) {
      auto got = rtu_ ? read_rtu(deadline) : read_mbap(deadline);
      if (!got) return fail(a, "timeout");
      Unframed u = rtu_ ? rtu_unframe(*got) : mbap_unframe(*got);
      if (!u.ok() && !(rtu_ && defects_.no_crc && u.error.find("CRC") != std::string::npos))
        return fail(a, "invalid_reply", u.error);
      if (!rtu_ && u.transaction != tid && !defects_.any_transaction) continue;  // no pending transaction: discard
      if (u.unit != unit) continue;  // an unexpected slave: the time-out keeps running (MB-SL v1.02 §2.4.1)
      return judged(a, r, f, pdu, u.pdu);
    }
  }

 private:
  json not_ready(const std::string& what) {
    json j{{"ready", false}, {"detail", what + ": " + std::strerror(errno)}};
    disconnect();
    return j;
  }
  static json fail(json a, const char* kind, const std::string& detail = "") {
    a["ok"] = false;
    a["error"] = kind;
    if (!detail.empty()) a["detail"] = detail;
    return a;
  }
  static json ok(json a, json values) {
    a["ok"] = true;
    a["values"] = std::move(values);
    return a;
  }

  bool over_limit(const json& r, uint8_t f) const {
    auto n = [&](const char* k) { return r.contains(k) ? int(r[k].is_array() ? r[k].size() : r[k].get<int>()) : 0; };
    switch (f) {
      case fc::read_coils:
      case fc::read_discrete_inputs: return n("count") > limits_.read_coils;
      case fc::read_holding_registers:
      case fc::read_input_registers: return n("count") > limits_.read_holding_registers;
      case fc::write_multiple_coils: return n("values") > limits_.write_multiple_coils;
      case fc::write_multiple_registers: return n("values") > limits_.write_multiple_registers;
      case fc::read_write_multiple_registers:
        return n("values") > limits_.rw_write || n("read_count") > limits_.read_holding_registers;
    }
    return false;
  }

  json judged(json a, const json& r, uint8_t f, const Bytes& req, const Bytes& rsp) {
    Judged j = judge_reply(req, rsp);
    if (j.kind == Judged::Kind::exception) {
      a["ok"] = false;
      a["error"] = "exception";
      a["code"] = j.exception_code;
      return a;
    }
    if (!j.ok()) {
      std::string why;
      for (const auto& p : j.problems) why += (why.empty() ? "" : "; ") + p;
      return fail(a, "invalid_reply", why);
    }
    if (f == fc::read_coils || f == fc::read_discrete_inputs) {
      json v = json::array();
      for (bool b : j.bits) v.push_back(b);
      return ok(a, v);
    }
    if (f == fc::encapsulated_interface) {
      ParsedReply p = parse_reply(rsp);
      json objects = json::object();
      for (const auto& o : p.reply->objects) {
        char key[8];
        std::snprintf(key, sizeof key, "0x%02X", o.id);
        objects[key] = std::string(o.value.begin(), o.value.end());
      }
      return ok(a, json{{"objects", objects}});
    }
    return ok(a, j.registers);
  }

  void drain() {
    uint8_t junk[512];
    for (;;) {
      pollfd p{fd_, POLLIN, 0};
      if (::poll(&p, 1, 0) <= 0 || ::read(fd_, junk, sizeof junk) <= 0) return;
    }
  }

  // Appends what arrives until `until`; false at the deadline or on EOF.
  bool read_more(Bytes& buf, Clock::time_point until) {
    auto left = std::chrono::duration_cast<std::chrono::milliseconds>(until - Clock::now()).count();
    if (left < 0) return false;
    pollfd p{fd_, POLLIN, 0};
    if (::poll(&p, 1, int(left)) <= 0) return false;
    uint8_t chunk[512];
    ssize_t n = ::read(fd_, chunk, sizeof chunk);
    if (n <= 0) return false;
    buf.insert(buf.end(), chunk, chunk + n);
    return true;
  }

  std::optional<Bytes> read_mbap(Clock::time_point deadline) {
    Bytes buf;
    for (;;) {
      auto h = parse_mbap(buf);
      if (h && buf.size() >= h->adu_size()) {
        Bytes adu(buf.begin(), buf.begin() + ptrdiff_t(h->adu_size()));
        return adu;
      }
      if (!read_more(buf, deadline)) return std::nullopt;
    }
  }

  // An RTU frame ends with the line's silence (MB-SL v1.02 §2.5.1.1): once
  // its function code's length is there, a t3.5 more must stay quiet, or
  // the frame is longer than its byte count says.
  std::optional<Bytes> read_rtu(Clock::time_point deadline) {
    Bytes buf;
    auto quiet = std::max<std::chrono::microseconds>(baud_ ? frame_gap(baud_) : 0us, 5ms);
    for (;;) {
      auto len = rtu_adu_length(buf, Direction::reply);
      bool whole = len && buf.size() >= *len;
      if (!buf.empty() && (whole || !len)) {
        if (!read_more(buf, Clock::now() + quiet)) return buf;  // silence: the frame ended
        continue;
      }
      if (!read_more(buf, deadline)) return std::nullopt;
    }
  }

  Defects defects_;
  client::Limits limits_;
  int fd_ = -1, baud_ = 0;
  bool rtu_ = false;
  uint16_t transaction_ = 0;
  std::chrono::milliseconds timeout_{500};
};

}  // namespace

int main(int argc, char** argv) {
  Defects d;
  for (int i = 1; i < argc; ++i) {
    std::string a = argv[i];
    if (a == "--defects" && i + 1 < argc) {
      std::string list = argv[++i];
      d.any_transaction = list.find("any-transaction") != std::string::npos;
      d.no_crc = list.find("no-crc") != std::string::npos;
      d.no_t35 = list.find("no-t35") != std::string::npos;
      d.no_turnaround = list.find("no-turnaround") != std::string::npos;
    } else {
      std::fprintf(stderr, "usage: broken_master [--defects any-transaction,no-crc,no-t35,no-turnaround]\n");
      return 2;
    }
  }
  std::optional<Master> m;
  try {
    m.emplace(d);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "broken_master: %s\n", e.what());
    return 2;
  }
  std::string line;
  while (std::getline(std::cin, line)) {
    json r = json::parse(line, nullptr, false);
    if (r.is_discarded() || !r.is_object()) continue;
    json out;
    if (r.contains("hello")) {
      out = {{"protocol", 1}, {"library", d.any_transaction || d.no_crc ? "broken-master" : "correct-master"},
             {"version", "1"}, {"raw", false}, {"retries", true},
             {"ops", {"read_coils", "read_discrete_inputs", "read_holding_registers", "read_input_registers",
                      "write_single_coil", "write_single_register", "write_multiple_coils", "write_multiple_registers",
                      "mask_write_register", "read_write_multiple_registers", "read_device_identification"}}};
    } else if (r.contains("connect")) {
      out = m->connect(r["connect"]);
    } else if (r.contains("disconnect")) {
      m->disconnect();
      out = {{"disconnected", true}};
    } else if (r.value("op", "") == "close") {
      break;
    } else {
      out = m->request(r);
    }
    std::cout << out.dump() << std::endl;
  }
  return 0;
}
