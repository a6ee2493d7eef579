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
