#include "serve/uart.h"

#include <fmt/core.h>
#include <termios.h>

#include <cmath>
#include <utility>

namespace mbc::serve {

std::string LineFormat::text() const { return fmt::format("{}-{}{}{}", baud, data_bits, parity, stop_bits); }

std::optional<LineFormat> parse_line_format(std::string_view text) {
  LineFormat f;
  std::string_view rate = text, format;
  if (auto dash = text.find('-'); dash != std::string_view::npos) rate = text.substr(0, dash), format = text.substr(dash + 1);
  if (rate.empty() || rate.size() > 7 || rate.find_first_not_of("0123456789") != std::string_view::npos) return std::nullopt;
  f.baud = std::stoi(std::string(rate));
  if (f.baud < 50 || f.baud > 4000000) return std::nullopt;
  if (!format.empty()) {
    if (format.size() != 3 || format[0] < '5' || format[0] > '8' || (format[2] != '1' && format[2] != '2')) return std::nullopt;
    const char p = char(std::toupper(static_cast<unsigned char>(format[1])));
    if (p != 'N' && p != 'E' && p != 'O') return std::nullopt;
    f.data_bits = format[0] - '0';
    f.parity = p;
    f.stop_bits = format[2] - '0';
  }
  return f;
}

const std::vector<LineFaultInfo>& line_faults() {
  static const std::vector<LineFaultInfo> all = {
      {LineFault::reply_gap, "reply-gap",
       "--line: every reply has a silence halfway between t1.5 and t3.5 in its middle (MB-SL v1.02 §2.5.1.1: at most t1.5)"},
      {LineFault::early_reply, "early-reply",
       "--line: replies one character time after the request ends, without the t3.5 silence before a frame"},
      {LineFault::line_noise, "line-noise",
       "--line: three noise bytes reach the master before every reply, t3.5 apart from it (a line without bias)"},
      {LineFault::keep_gapped_request, "keep-gapped-request",
       "--line: answers a request with a silence over t1.5 inside it, which MB-SL v1.02 §2.5.1.1 says to discard"},
  };
  return all;
}

std::optional<LineFault> line_fault_named(std::string_view name) {
  for (const auto& f : line_faults())
    if (name == f.name) return f.fault;
  return std::nullopt;
}

int baud_of_speed(unsigned speed) {
  static const std::pair<speed_t, int> table[] = {
      {B50, 50},         {B75, 75},         {B110, 110},       {B134, 134},       {B150, 150},
      {B200, 200},       {B300, 300},       {B600, 600},       {B1200, 1200},     {B1800, 1800},
      {B2400, 2400},     {B4800, 4800},     {B9600, 9600},     {B19200, 19200},   {B38400, 38400},
      {B57600, 57600},   {B115200, 115200}, {B230400, 230400}, {B460800, 460800}, {B500000, 500000},
      {B576000, 576000}, {B921600, 921600}, {B1000000, 1000000}};
  for (auto [s, b] : table)
    if (s == speed) return b;
  return 0;
}

namespace {

// The wire as a sequence of bit levels, one per bit time at tx.
std::vector<bool> wire_bits(std::span<const uint8_t> bytes, const LineFormat& f) {
  std::vector<bool> bits;
  bits.reserve(bytes.size() * size_t(f.bits_per_char()));
  for (uint8_t b : bytes) {
    bits.push_back(false);  // start bit
    int ones = 0;
    for (int i = 0; i < f.data_bits; ++i) {
      bool one = (b >> i) & 1;
      ones += one;
      bits.push_back(one);
    }
    if (f.parity == 'E') bits.push_back(ones % 2 == 1);
    if (f.parity == 'O') bits.push_back(ones % 2 == 0);
    for (int i = 0; i < f.stop_bits; ++i) bits.push_back(true);
  }
  return bits;
}

}  // namespace

std::vector<uint8_t> resample(std::span<const uint8_t> bytes, const LineFormat& tx, const LineFormat& rx) {
  if (tx.baud == rx.baud && tx.data_bits == rx.data_bits && tx.parity == rx.parity && tx.stop_bits == rx.stop_bits)
    return {bytes.begin(), bytes.end()};
  const std::vector<bool> bits = wire_bits(bytes, tx);
  // Times in units of the sender's bit time; the receiver's bit time in those units.
  const double rx_bit = double(tx.baud) / double(rx.baud);
  auto level = [&](double t) {
    if (t < 0) return true;
    auto i = size_t(t);
    return i >= bits.size() ? true : bool(bits[i]);
  };
  std::vector<uint8_t> out;
  const double end = double(bits.size());
  double t = 0;  // where the receiver looks for the next start bit
  while (t < end) {
    // The next falling edge at or after t: the sender's levels change only at whole bit times.
    auto i = size_t(std::ceil(t));
    while (i < bits.size() && !(bits[i] == false && level(double(i) - 0.5))) ++i;
    if (i >= bits.size()) break;
    const double t0 = double(i);
    if (level(t0 + 0.5 * rx_bit)) {  // a glitch, not a start bit
      t = t0 + 0.5 * rx_bit;
      continue;
    }
    unsigned value = 0;
    int ones = 0;
    for (int k = 0; k < rx.data_bits; ++k)
      if (level(t0 + (1.5 + k) * rx_bit)) value |= 1u << k, ++ones;
    double at = t0 + (1.5 + rx.data_bits) * rx_bit;
    bool ok = true;
    if (rx.parity != 'N') {
      bool p = level(at);
      ok = rx.parity == 'E' ? p == (ones % 2 == 1) : p == (ones % 2 == 0);
      at += rx_bit;
    }
    ok = ok && level(at);  // the stop bit
    if (ok) out.push_back(uint8_t(value));
    t = at + 0.5 * rx_bit;  // looks for the next edge after the middle of the stop bit
  }
  return out;
}

}  // namespace mbc::serve
