#include "modbus/rtu.h"

#include "modbus/crc16.h"
#include "modbus/function_codes.h"
#include "modbus/text.h"

namespace mbc {

using std::chrono::microseconds;

Bytes rtu_frame(uint8_t slave, std::span<const uint8_t> pdu) {
  Bytes b;
  b.reserve(pdu.size() + kRtuAddress + kRtuCrc);
  b.push_back(slave);
  b.insert(b.end(), pdu.begin(), pdu.end());
  append_crc(b);
  return b;
}

Unframed rtu_unframe(std::span<const uint8_t> adu) {
  Unframed u;
  if (adu.size() < kRtuAddress + 1 + kRtuCrc) {
    u.error = strf("%zu bytes: too short for an RTU frame (address, function code, CRC)", adu.size());
    return u;
  }
  u.unit = adu[0];
  u.pdu.assign(adu.begin() + kRtuAddress, adu.end() - kRtuCrc);
  if (adu.size() > kMaxRtuAdu) u.error = strf("%zu bytes: over the %zu of an RTU frame (MB-SL v1.02 §2.5.1)", adu.size(), kMaxRtuAdu);
  else if (!crc_ok(adu)) {
    uint16_t c = crc16(adu.first(adu.size() - kRtuCrc));
    u.error = strf("CRC %02X %02X, expected %02X %02X", adu[adu.size() - 2], adu[adu.size() - 1], c & 0xFF, c >> 8);
  }
  return u;
}

std::optional<size_t> rtu_adu_length(std::span<const uint8_t> head, Direction dir) {
  constexpr size_t slave_fc = kRtuAddress + 1, crc = kRtuCrc;
  if (head.size() < 2) return std::nullopt;
  // A byte count at head[count_at] gives the rest.
  auto with_count = [&](size_t count_at) -> std::optional<size_t> {
    if (head.size() <= count_at) return std::nullopt;
    return count_at + 1 + head[count_at] + crc;
  };
  auto fixed = [&](size_t data) -> std::optional<size_t> { return slave_fc + data + crc; };
  uint8_t code = head[1];
  if (dir == Direction::request) {
    switch (code) {
      case fc::read_coils: case fc::read_discrete_inputs:                // address, quantity (§6.1-6.4)
      case fc::read_holding_registers: case fc::read_input_registers:
      case fc::write_single_coil: case fc::write_single_register:        // address, value (§6.5, §6.6)
      case fc::diagnostics:                                              // sub-function, data (§6.8)
        return fixed(4);
      case fc::read_exception_status: case fc::get_comm_event_counter:   // no data (§6.7, §6.9, §6.10, §6.13)
      case fc::get_comm_event_log: case fc::report_server_id:
        return fixed(0);
      case fc::write_multiple_coils: case fc::write_multiple_registers:  // address, quantity, count (§6.11, §6.12)
        return with_count(6);
      case fc::read_file_record: case fc::write_file_record:             // byte count, sub-requests (§6.14, §6.15)
        return with_count(2);
      case fc::mask_write_register:                                      // address, AND mask, OR mask (§6.16)
        return fixed(6);
      case fc::read_write_multiple_registers:                            // 4 words, byte count, values (§6.17)
        return with_count(10);
      case fc::read_fifo_queue:                                          // FIFO pointer address (§6.18)
        return fixed(2);
      case fc::encapsulated_interface:  // MEI type 14: read device id code, object id (§6.21)
        if (head.size() < 3) return std::nullopt;
        return head[2] == kMeiReadDeviceId ? fixed(3) : std::nullopt;
      default:
        return std::nullopt;
    }
  }
  if (code & kExceptionBit) return fixed(1);  // exception code (§7)
  switch (code) {
    case fc::read_coils: case fc::read_discrete_inputs:               // byte count, data (§6.1-6.4)
    case fc::read_holding_registers: case fc::read_input_registers:
    case fc::get_comm_event_log: case fc::report_server_id:           // byte count, ... (§6.10, §6.13)
    case fc::read_file_record: case fc::write_file_record:            // byte count, ... (§6.14, §6.15)
    case fc::read_write_multiple_registers:                           // byte count, values (§6.17)
      return with_count(2);
    case fc::write_single_coil: case fc::write_single_register:       // echo of address and value/quantity
    case fc::write_multiple_coils: case fc::write_multiple_registers: // (§6.5, 6.6, 6.11, 6.12)
    case fc::get_comm_event_counter:                                  // status, event count (§6.9)
      return fixed(4);
    case fc::diagnostics:  // echo of sub-function and data: 2 data bytes for all but "return query data" (§6.8)
      return fixed(4);
    case fc::read_exception_status:  // one status byte (§6.7)
      return fixed(1);
    case fc::mask_write_register:  // echo of address, AND and OR masks (§6.16)
      return fixed(6);
    case fc::read_fifo_queue:  // two-byte byte count (§6.18)
      if (head.size() < 4) return std::nullopt;
      return fixed(2 + be16(head, 2));
    default:  // FC 43 and unknown codes: the line's silence ends the frame
      return std::nullopt;
  }
}

bool rtu_adu_complete(std::span<const uint8_t> bytes, Direction dir) {
  auto n = rtu_adu_length(bytes, dir);
  return n && bytes.size() == *n && crc_ok(bytes);
}

microseconds frame_gap(int baud) {
  if (baud > 19200) return microseconds(1750);  // MB-SL v1.02 §2.5.1.1
  return microseconds(int64_t(3.5 * kBitsPerChar * 1e6 / baud + 0.5));
}

microseconds char_gap(int baud) {
  if (baud > 19200) return microseconds(750);  // MB-SL v1.02 §2.5.1.1
  return microseconds(int64_t(1.5 * kBitsPerChar * 1e6 / baud + 0.5));
}

microseconds wire_time(size_t bytes, int baud) {
  return microseconds(int64_t(double(bytes) * kBitsPerChar * 1e6 / baud + 0.5));
}

}  // namespace mbc
