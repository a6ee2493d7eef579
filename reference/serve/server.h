// `mbconform serve`: reference devices on real transports. One thread, one
// poll loop, non-blocking descriptors: Modbus TCP (MBAP), RTU over TCP, and
// RTU on a pseudo-terminal a master opens like a serial port. Framing lives
// here; every protocol decision (broadcast, foreign slave ids, bad CRC,
// exceptions) is the engine's, through ref::Bus.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "modbus/framing.h"
#include "engine/device.h"
#include "faults/faults.h"
#include "serve/tls_door.h"
#include "serve/uart.h"

namespace mbc::serve {

// tls: Modbus/TCP Security (MBAP inside TLS, tls_door.h).
// Transport: modbus/framing.h's (tcp, rtu-tcp, pty, tls).

struct Endpoint {
  Transport transport = Transport::tcp;
  std::string host = "127.0.0.1";  // tcp, rtu-tcp
  uint16_t port = 0;               // 0: the system picks one
  std::string path;                // pty: the symlink a master opens
};

// "HOST:PORT", ":PORT", "PORT" or "[v6]:PORT" for tcp and rtu-tcp; a path for
// pty. Throws std::invalid_argument saying what is wrong.
Endpoint parse_endpoint(Transport t, const std::string& text);

// "hsc60@2" -> {"hsc60", 2}; "hsc60" -> slave 1. Throws std::invalid_argument.
struct DeviceArg {
  std::string id;
  uint8_t slave = 1;
};
DeviceArg parse_device_arg(const std::string& text);

struct Options {
  std::vector<Endpoint> endpoints;
  std::string eeprom_dir;        // empty: no persistence across restarts
  int baud = 19200;              // the pty's nominal rate: sets the frame gap
  std::optional<int> line_rate;  // pace RTU replies at this rate's wire time
  // The serial line a pty stands for (--line 19200-8E1): a master at another
  // baud rate reads and sends what a UART at the wrong rate would (uart.h).
  // Sets baud and line_rate to its rate.
  std::optional<LineFormat> line;
  // With `line`: a USB adapter's latency timer, the device's turnaround
  // delay, and the line faults (uart.h). Every byte then takes its character
  // time both ways: a request reaches the device as the line clocks it in
  // (a silence over t1.5 inside it makes it discarded, MB-SL v1.02
  // §2.5.1.1), and each byte of a reply reaches the master when its last bit
  // would have.
  LineBehaviour behaviour;
  // The master's adapter echoes its request back on the pty as it goes out
  // (2-wire RS-485 adapters without echo suppression).
  bool echo = false;
  bool trace = false;            // every frame to stderr, timestamped (trace.h)
  std::string pcap;              // every frame to this pcapng file (trace.h: PcapTrace)
  faults::FaultSet faults;       // injected into every device served (empty: correct devices)
  // A TCP connection that sent nothing for this long is closed (0: never).
  // The default is one no CI gate reaches.
  int idle_timeout_s = 600;
  // TCP connections served at once; at the cap the oldest unused one is
  // closed for the newcomer (Modbus Messaging on TCP/IP Implementation Guide
  // V1.0b §4.2.1.2).
  size_t max_connections = 4096;
  TlsOptions tls;  // for Transport::tls endpoints
  bool quiet = false;  // `serve -q`: no "listening" lines (errors still go to stderr)
};

class Server {
 public:
  // Restores each device's EEPROM image from options.eeprom_dir (then power-cycles it).
  Server(ref::Bus bus, Options options);
  ~Server();  // closes descriptors, removes pty symlinks
  Server(const Server&) = delete;
  Server& operator=(const Server&) = delete;

  // Opens every endpoint, then prints "listening <transport> <address>" per
  // endpoint on stdout. Throws std::runtime_error when one cannot be opened.
  void open();
  // Serves until SIGINT or SIGTERM, then saves the EEPROM images. Returns 0.
  // Every round does bounded work per connection (input read up to a bound,
  // frames consumed in linear time, no reading from a client whose replies
  // pile up unread), so a stop signal is seen within one round whatever the
  // clients do.
  int run();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace mbc::serve
