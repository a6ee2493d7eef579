// The one seam between conformance code and the thing under test. Cases,
// properties and the black-box fuzzer speak PDUs (and, for framing cases, raw
// ADUs) to a Target; they never know whether it is the in-process reference,
// a drive behind libmodbus on a serial line, Modbus TCP, RTU over TCP or a
// vendor stack loaded as a plugin. One file per kind under conformance/targets/.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <stdexcept>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "modbus/framing.h"
#include "modbus/hex.h"

namespace mbc::conf {

// How the target frames a PDU: modbus/'s one descriptor (mbc::kRtu: RTU,
// on a serial line or over TCP; mbc::kTcp: the MBAP header, on TCP or TLS).
using Framing = const mbc::Framing*;

// What answers behind a target, by its URI's scheme (mbtls: tls). The one
// form of the idea: code compares the enum, to_string() gives the name that
// reports, notes and JSON print.
enum class TargetKind { ref, tcp, rtu_tcp, rtu, tls, plugin };
const char* to_string(TargetKind k);  // "ref", "tcp", "rtu-tcp", "rtu", "tls", "plugin"
// The kind a URI scheme opens ("mbtls" opens tls); nullopt for a scheme no
// target kind takes.
std::optional<TargetKind> kind_of_scheme(std::string_view scheme);
// The kind `u` opens; throws invalid_argument naming `text` for a scheme no
// kind takes (open_target and `run --plan` say the same line).
struct Uri;
TargetKind kind_of_uri(const Uri& u, const std::string& text);
// What a kind is before it is opened, decided here once: the framing its
// frames go out in, and whether it is a real device (the frame policy's
// default deny). Every target takes them from here, and so does `run --plan`.
Framing framing_of(TargetKind k);
bool is_live(TargetKind k);

struct TargetInfo {
  std::string uri;        // as given (normalised)
  TargetKind kind = TargetKind::ref;
  Framing framing = &mbc::kRtu;
  uint8_t unit = 1;       // the slave id / unit id cases address
  bool live = false;      // a real device: the safety rules apply
  bool virtual_clock = false;  // advance() moves the device's time
  bool power_cycle = false;    // power_cycle() is available
  bool raw = false;            // send_raw() is available (malformed frames)
  std::optional<int> baud;     // serial line rate, for the wire-time bound
  std::string device_id;       // the spec a ref: target carries, else empty
  std::string implementation;  // what answers, as it names itself (plugin: the stack's name)
  // What the user should know of how this target was opened (a USB adapter's
  // latency timer, ...), one line each; commands print them.
  std::vector<std::string> notes;
  // A USB serial adapter's latency timer as read on open (sysfs), in ms: it
  // hands received bytes over in batches that far apart. Unset: not a USB
  // adapter, or not readable (a pty, a native UART).
  std::optional<int> latency_timer_ms;
};

// One exchange. `frame` is what came back, as received (RTU: slave..CRC;
// MBAP: header..PDU), empty on silence. `pdu` is set when a frame arrived
// whose framing was valid (CRC right, slave/unit and transaction matching);
// otherwise `framing_error` says what was wrong with it.
// A reply to an earlier request that came after that request had been
// judged silent (late_replies() counts it), found waiting before a later
// request went out or in front of that request's reply.
struct LateReply {
  Bytes frame;    // as received
  Bytes request;  // the request it answers, as framed, when the target could tell which; else empty
  std::chrono::microseconds after{0};  // from that request going out to when it was found (request known)
};

struct Reply {
  Bytes request;   // the bytes sent, as framed on the wire
  Bytes frame;
  std::optional<Bytes> pdu;
  std::string framing_error;
  std::chrono::microseconds latency{0};  // request sent -> last byte received (or timeout)
  bool closed = false;  // the peer closed the connection instead of answering (TCP kinds)
  // Late replies to earlier requests found during this exchange (RTU kinds).
  // One to a frame that had to stay silent (broadcast, another slave id, a
  // corrupted frame: MB-SL v1.02 §2.1, §2.4.2) is that frame's fault.
  std::vector<LateReply> late;
  // On a serial line (rtu://): when the request's writing began, and each
  // read of the exchange as it came (when, how many bytes), the adapter's
  // echo and any line noise included; conformance/timing/ judges a drive's
  // timing by them (MB-SL v1.02 §2.5.1.1). Empty elsewhere.
  struct Arrival {
    std::chrono::steady_clock::time_point at;
    size_t bytes = 0;
  };
  std::chrono::steady_clock::time_point sent_at{};
  std::vector<Arrival> arrivals;
  size_t echo_bytes = 0;  // the adapter's echo of the request, stripped from the front
  Bytes noise;            // bytes before the reply that were no frame (line noise), split off
  bool silent() const { return frame.empty(); }
};

// A fault of the thing under test that the target recovered from (a plugin
// that crashed or hung; its host was restarted): that exchange failed, and
// the target is usable again. It never counts toward a lost target.
struct RecoveredFault : std::runtime_error {
  using std::runtime_error::runtime_error;
};

class Target {
 public:
  virtual ~Target() = default;
  virtual const TargetInfo& info() const = 0;

  // Sends a well-formed request `pdu` to `unit` (0 = broadcast) and waits for
  // the reply; on silence returns a Reply with an empty frame once the silence
  // window has passed.
  virtual Reply transact(uint8_t unit, std::span<const uint8_t> pdu) = 0;
  Reply transact(std::span<const uint8_t> pdu) { return transact(info().unit, pdu); }

  // Sends `bytes` exactly as given (for RTU framing: a whole ADU, possibly
  // malformed; `gap_after` splits it by an inter-character pause after that
  // many bytes). Only when info().raw; throws std::logic_error otherwise.
  virtual Reply send_raw(std::span<const uint8_t> bytes, std::optional<size_t> gap_after = std::nullopt) = 0;

  // Several well-formed requests, one Reply each, in order. Where the
  // transport pairs replies with requests by itself (Modbus TCP transaction
  // ids, MB Messaging on TCP/IP v1.0b §3.1.3 and Implementation Guide §4.2)
  // up to `depth` requests are out before their replies come, and a silence
  // costs one wait at the end of the batch instead of one per request;
  // elsewhere one transact after another (the default). Waits as set_wait.
  struct Request {
    uint8_t unit = 0;
    std::span<const uint8_t> pdu;
  };
  virtual std::vector<Reply> transact_all(std::span<const Request> requests, size_t depth = 16);
  // Whether transact_all has requests out at once on this target.
  virtual bool pipelines() const { return false; }

  // The pause `send_raw` makes inside a split frame, where the target chose
  // it (nullopt: no pause of its own, or one the user fixed with `gap=`). A
  // receiver that a busy host holds up longer than that reads both parts as
  // one frame; the runner then runs the case again with a longer pause.
  virtual std::optional<std::chrono::microseconds> split_gap() const { return std::nullopt; }
  // Kept until set again; zero gives back the target's own pause.
  virtual void set_split_gap(std::chrono::microseconds) {}

  // How long a negative case waits for silence. Live targets measure their
  // latency and keep this a bounded multiple of it.
  virtual std::chrono::microseconds silence_window() const { return std::chrono::microseconds(0); }

  // How long a live target waits for the first byte of a reply. A reply that
  // is expected (normal or exception) costs nothing to wait for, so only an
  // expected silence is worth the short adaptive window; waiting the timeout
  // for a reply keeps a late one (a loaded host, a server that sleeps before
  // an exception) from becoming a false "silence" verdict.
  enum class Wait {
    automatic,  // a well-formed request to info().unit: up to the timeout; broadcast, other units, raw frames: the window
    window,     // the silence window (silence expected, or not cared about: fuzzing)
    reply,      // up to the timeout (a reply is expected)
  };
  // Applies to every exchange until changed.
  virtual void set_wait(Wait) {}

  // How many replies came after their request had been judged silent (a
  // late reply, recognised by its transaction id or found waiting on the
  // line before the next request). Each one widens the silence window; the
  // runner re-runs the cases judged since (runner/runner.cpp).
  virtual uint64_t late_replies() const { return 0; }

  // Closes and reopens the connection (a wedged or reset socket); false when
  // the kind has nothing to reopen or it failed.
  virtual bool reconnect() { return false; }

  // Virtual time and power (ref and plugin targets); throw std::logic_error
  // when the info() flag is false.
  virtual void advance(std::chrono::microseconds dt) = 0;
  virtual void power_cycle() = 0;
  // A fault the drive detects, caused out of band where the bus gives no way
  // to cause one (a CiA 402 layout): ref targets take the control model's
  // `fault` step (ref::Device::trip_fault()). False when the kind cannot, or
  // the device's model has no fault step.
  virtual bool trip_fault() { return false; }
};

// Opens a target by URI:
//   ref:<device-id>[?unit=N&fault=NAME[,NAME]]
//   tcp://HOST:PORT?unit=N   rtu-tcp://HOST:PORT?unit=N
//   rtu:///dev/ttyUSB0?baud=115200&parity=N&data=8&stop=1&unit=N
//   plugin:PATH.so[?device=ID&unit=N&config=TEXT]
//   mbtls://HOST[:802]?cert=FILE&key=FILE&ca=FILE[&unit=N]  (tls_target.cpp)
// Live kinds also take timeout=MS (the longest wait for a reply and for the
// connection, default 1000), silence=MS (a fixed silence window instead of
// the measured one) and gap=MS (the pause of a split frame, RTU kinds).
// rtu:// defaults to the standard's 19200 baud 8E1 (MB-SL v1.02 §2.5.1).
// Throws std::invalid_argument (bad URI) or std::runtime_error (cannot open).
std::unique_ptr<Target> open_target(const std::string& uri);

// The URI split into its parts ("rtu:///dev/ttyUSB0?baud=9600" ->
// scheme rtu, path /dev/ttyUSB0, query {baud: 9600}).
struct Uri {
  std::string scheme;
  std::string host;
  uint16_t port = 0;
  std::string path;
  std::vector<std::pair<std::string, std::string>> query;
  std::optional<std::string> param(const std::string& key) const;
};
Uri parse_uri(const std::string& text);  // throws std::invalid_argument

}  // namespace mbc::conf
