// The serial line a served pty stands for (`serve --pty PATH --line
// 19200-8E1`). A pty carries bytes, not bits: a master that opens it at the
// wrong baud rate would still read every byte. A real line does not: a UART
// samples the wire at its own rate, and a character sent at another rate
// comes out as other bytes, framing errors, or nothing. This file models that
// sampling, so a master (or `mbconform scan`) set to the wrong rate gets
// garbage or silence from a served line, as from a drive.
//
// What a pty shows: the master's baud rate (its termios speed is shared with
// the pty's master side). What it does not: parity, data and stop bits
// (Linux's pty driver forces CS8 without parity on both sides), so a wrong
// parity is not modelled; the line's own format still sets its timing.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace mbc::serve {

struct LineFormat {
  int baud = 19200;
  int data_bits = 8;
  char parity = 'E';  // N, E or O
  int stop_bits = 1;
  // Start bit, data bits, parity bit and stop bits.
  int bits_per_char() const { return 1 + data_bits + (parity == 'N' ? 0 : 1) + stop_bits; }
  std::string text() const;  // "19200-8E1"
  // One character's time on the wire.
  std::chrono::microseconds char_time() const {
    return std::chrono::microseconds(int64_t(double(bits_per_char()) * 1e6 / baud + 0.5));
  }
  // t1.5 and t3.5 in this format's character times; above 19200 baud the
  // fixed 750 us and 1.75 ms MB-SL v1.02 §2.5.1.1 recommends.
  std::chrono::microseconds t15() const {
    return baud > 19200 ? std::chrono::microseconds(750) : std::chrono::microseconds(char_time().count() * 3 / 2);
  }
  std::chrono::microseconds t35() const {
    return baud > 19200 ? std::chrono::microseconds(1750) : std::chrono::microseconds(char_time().count() * 7 / 2);
  }
};

// What the line does besides carrying characters, as real hardware does
// (serve --latency-timer, --turnaround, and the line faults --fault takes).
// Only with a modelled line (--line): every byte then takes its character
// time both ways.
enum class LineFault : uint8_t {
  reply_gap,           // a silence between t1.5 and t3.5 in the middle of every reply
  early_reply,         // replies one character time after the request, before t3.5
  line_noise,          // three noise bytes, then t3.5, before every reply
  keep_gapped_request, // answers a request with a silence over t1.5 inside it
};
struct LineFaultInfo {
  LineFault fault;
  const char* name;
  const char* description;
};
const std::vector<LineFaultInfo>& line_faults();
// The line fault named `name`, nullopt when it is none.
std::optional<LineFault> line_fault_named(std::string_view name);

struct LineBehaviour {
  // The master's USB adapter hands what it received to the host when its
  // latency timer runs out (FTDI: 16 ms by default, 1..255): bytes reach the
  // master in batches at multiples of it. 0: each byte at its time.
  std::chrono::milliseconds latency_timer{0};
  // The device waits this long after t3.5 before it replies (a drive's
  // response delay parameter).
  std::chrono::microseconds turnaround{0};
  std::vector<LineFault> faults;
  bool has(LineFault f) const {
    for (auto x : faults)
      if (x == f) return true;
    return false;
  }
};

// "19200-8E1", "9600-8N2", "115200" (8E1, MB-SL v1.02 §2.5.1's default
// format); nullopt when it is not one.
std::optional<LineFormat> parse_line_format(std::string_view text);

// The baud rate of a termios speed constant (B9600 -> 9600), 0 when unknown.
int baud_of_speed(unsigned speed);

// What a receiver set to `rx` reads from `bytes` sent back to back at `tx`:
// the wire's bits (start bit, data LSB first, parity, stop bits, idle high)
// sampled as a UART does, at the middle of each of its bit times after a
// falling edge. A character whose stop bit does not read high is a framing
// error and is dropped (the driver's default, IGNPAR off, delivers a NUL in
// its place on some drivers; dropping is the case a master sees as a short,
// bad frame). The same bytes when the two agree on rate and format.
std::vector<uint8_t> resample(std::span<const uint8_t> bytes, const LineFormat& tx, const LineFormat& rx);

}  // namespace mbc::serve
