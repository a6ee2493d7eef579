// The scenario server: the device a master under test talks to. It listens on
// one transport (Modbus TCP, RTU over TCP, or a pty the adapter opens like a
// serial port), splits the byte stream into request frames (modbus/ framing),
// keeps each one with its timing, and answers it as the current step says:
// correctly from the data model, or with one named fault.
//
// It never blocks and owns no thread: the runner polls its descriptors
// together with the adapter's pipes (fill_poll / on_poll) and wakes it at
// its next due time.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <poll.h>

#include "client/scenario.h"
#include "modbus/bytes.h"
#include "modbus/framing.h"

namespace mbc::client {

using Clock = std::chrono::steady_clock;

// Transport: modbus/framing.h's. The scenario servers serve tcp, rtu-tcp and
// pty; tls is tcp behind a TLS front (client/tls_front.h).

// One request frame as the master sent it.
struct SeenRequest {
  Bytes adu;                     // the whole frame
  Clock::time_point first, last; // its first and last byte's arrival
  std::chrono::microseconds max_gap{0};        // the longest silence inside it
  std::optional<std::chrono::microseconds> gap_before;  // silence since the line's previous traffic
  int step = -1;                 // the step it arrived during
};

// One frame (or piece) the server sent, for the report.
struct SentFrame {
  Bytes bytes;
  Clock::time_point at;
  std::string what;
};

class ScenarioServer {
 public:
  // Opens the endpoint: TCP on 127.0.0.1 port 0, or a pty linked at `pty_path`.
  ScenarioServer(Transport t, std::string pty_path, int baud);
  ~ScenarioServer();
  ScenarioServer(const ScenarioServer&) = delete;
  ScenarioServer& operator=(const ScenarioServer&) = delete;

  Transport transport() const { return transport_; }
  uint16_t port() const { return port_; }
  const std::string& pty_path() const { return pty_path_; }

  // The step now being run and how to answer it; requests arriving are tagged with `index`.
  void set_step(int index, const ScenarioStep* step, std::chrono::milliseconds master_timeout);
  // Forget the requests and frames seen (a new scenario).
  void clear();
  // Drop the accepted connection (the adapter disconnected) and pending sends.
  void drop_connection();

  // Poll integration: append descriptors, handle their events, and say when
  // the next scheduled send is due.
  void fill_poll(std::vector<pollfd>& fds) const;
  void on_poll(const std::vector<pollfd>& fds);
  std::optional<Clock::time_point> next_due() const;
  void on_time();
  bool idle() const { return pending_.empty(); }

  const std::vector<SeenRequest>& requests() const { return requests_; }
  const std::vector<SentFrame>& sent() const { return sent_; }

 private:
  struct Pending {
    Clock::time_point due;
    Bytes bytes;
    std::string what;
  };
  int data_fd() const;
  std::chrono::microseconds quiet() const;  // the silence that ends a frame of unknown length
  void accept_one();
  void read_some();
  void take_frames(bool gap_seen);
  void answer(const SeenRequest& r);
  void send_now(const Pending& p);
  void schedule(std::chrono::microseconds after, Bytes bytes, std::string what);
  Bytes frame_reply(uint8_t unit, uint16_t transaction, const Bytes& pdu) const;

  Transport transport_;
  std::string pty_path_;
  int baud_;
  int listen_fd_ = -1, conn_fd_ = -1, pty_master_ = -1, pty_slave_ = -1;
  uint16_t port_ = 0;
  Bytes buf_;
  std::vector<Clock::time_point> arrivals_;  // one per byte of buf_
  Clock::time_point last_traffic_{};
  bool any_traffic_ = false;
  int step_index_ = -1;
  const ScenarioStep* step_ = nullptr;
  std::chrono::milliseconds master_timeout_{500};
  int answered_in_step_ = 0;
  std::vector<Pending> pending_;
  std::vector<SeenRequest> requests_;
  std::vector<SentFrame> sent_;
};

}  // namespace mbc::client
