// libmodbus's server side as a function: modbus_reply() on a modbus_mapping_t
// that mirrors the modbus-standard spec's first 256 items of each table
// (coils, discrete inputs, input and holding registers 0x0000..0x00FF).
// An RTU context is bound to one end of a socketpair (modbus_set_socket), so
// the reply modbus_reply writes, CRC included, is read back from the other end.
// Used by differential_fuzzer and libmodbus_reply_fuzzer (the bench baseline).
#pragma once

#include <modbus.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <unistd.h>
#include <fcntl.h>

#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <optional>
#include <span>

#include "modbus/hex.h"

namespace mbc::fuzz {

class LibmodbusServer {
 public:
  static constexpr int kItems = 256;  // each table, from address 0

  explicit LibmodbusServer(uint8_t slave) {
    if (socketpair(AF_UNIX, SOCK_STREAM, 0, fds_) != 0) std::abort();
    fcntl(fds_[1], F_SETFL, O_NONBLOCK);
    ctx_ = modbus_new_rtu("/dev/null", 19200, 'E', 8, 1);  // never opened: the socket below replaces it
    map_ = modbus_mapping_new_start_address(0, kItems, 0, kItems, 0, kItems, 0, kItems);
    if (!ctx_ || !map_) std::abort();
    modbus_set_slave(ctx_, slave);
    // modbus_reply sleeps one response timeout before some exception replies
    // (to let a serial line drain, then flushes it): make that 1 µs, or every
    // such request costs 0.5 s. It changes no reply byte.
    // 1 µs, and a timer slack of 1 ns, or the kernel's default 50 µs slack makes
    // that sleep dominate the baseline's cost.
    modbus_set_response_timeout(ctx_, 0, 1);
    prctl(PR_SET_TIMERSLACK, 1UL, 0, 0, 0);
    modbus_set_socket(ctx_, fds_[0]);
  }
  ~LibmodbusServer() {
    modbus_set_socket(ctx_, -1);
    modbus_free(ctx_);
    modbus_mapping_free(map_);
    close(fds_[0]);
    close(fds_[1]);
  }
  LibmodbusServer(const LibmodbusServer&) = delete;
  LibmodbusServer& operator=(const LibmodbusServer&) = delete;

  modbus_mapping_t& map() { return *map_; }

  // The reply to one RTU ADU (slave, PDU, CRC) the caller has already framed
  // as a libmodbus receiver would deliver it; nullopt when nothing was sent.
  std::optional<Bytes> reply(std::span<const uint8_t> adu) {
    // modbus_reply trusts the receive layer for the length and reads the
    // fields the function code implies: give it a full-size buffer.
    uint8_t buf[MODBUS_RTU_MAX_ADU_LENGTH + 16] = {};
    size_t n = adu.size() < sizeof buf ? adu.size() : sizeof buf;
    std::memcpy(buf, adu.data(), n);
    modbus_reply(ctx_, buf, int(n), map_);
    Bytes out;
    uint8_t chunk[512];
    for (;;) {
      ssize_t r = read(fds_[1], chunk, sizeof chunk);
      if (r <= 0) break;
      out.insert(out.end(), chunk, chunk + r);
    }
    if (out.empty()) return std::nullopt;
    return out;
  }

 private:
  int fds_[2] = {-1, -1};
  modbus_t* ctx_ = nullptr;
  modbus_mapping_t* map_ = nullptr;
};

}  // namespace mbc::fuzz
