// Modbus PDUs (function code + data, no address, no CRC, no MBAP), built and
// parsed in both directions for every function code of MBAP v1.1b3 §6 that
// the spec language knows: 01-08, 0B, 0C, 0F-11, 14-18, 2B/0E; exceptions §7.
//
// parse_* decode the layout and say precisely what is wrong when it does not
// hold. build_request / build_reply write exactly the fields given (byte
// counts and quantities included, so an inconsistent request can be built on
// purpose); the named builders below compute them.
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "modbus/bytes.h"

namespace mbc {

enum class Direction { request, reply };

// One file record sub-request or sub-response (§6.14, §6.15).
struct FileRecord {
  uint8_t reference_type = 6;  // "must be specified as 6"
  uint16_t file = 0;           // FC 20/21 requests, FC 21 replies
  uint16_t record = 0;         // FC 20/21 requests, FC 21 replies
  uint16_t length = 0;         // record length in words (FC 20 request; FC 21: data.size())
  std::vector<uint16_t> data{};  // FC 21 request and reply, FC 20 reply
};

// One object of a Read Device Identification reply (§6.21).
struct DeviceIdObject {
  uint8_t id = 0;
  Bytes value{};
};

struct Request {
  uint8_t function = 0;
  uint16_t address = 0;   // FC 01-06, 0F, 10, 16; FC 17: read address; FC 18: FIFO pointer address
  uint16_t quantity = 0;  // FC 01-04, 0F, 10; FC 17: read quantity
  uint16_t value = 0;     // FC 05 (0xFF00 on, 0x0000 off), FC 06
  uint16_t write_address = 0, write_quantity = 0;  // FC 17
  uint16_t and_mask = 0, or_mask = 0;              // FC 16
  uint16_t sub_function = 0;                       // FC 08
  uint8_t mei_type = 0;                            // FC 2B
  uint8_t read_device_id_code = 0, object_id = 0;  // FC 2B, MEI 0E
  uint8_t byte_count = 0;                          // as sent: FC 0F, 10, 14, 15, 17
  std::vector<uint16_t> registers{};                 // FC 10; FC 17: write values
  std::vector<bool> coils{};                         // FC 0F: `quantity` bits (fewer if the data is short)
  Bytes data{};  // FC 08: data field; FC 2B other than MEI 0E and unknown codes: the bytes after the code
  std::vector<FileRecord> files{};  // FC 14, 15
};

struct ParsedRequest {
  std::optional<Request> request;  // set when the layout decoded
  // Why it did not: "FC10 request: byte count 4 but 2 data bytes follow".
  std::string error;
  // Decoded, but a rule of §6 is broken: byte count != what the quantity
  // needs, FC 05 value other than FF00/0000, PDU over 253 bytes.
  std::vector<std::string> problems;
  bool ok() const { return request.has_value() && problems.empty(); }
};
ParsedRequest parse_request(std::span<const uint8_t> pdu);
Bytes build_request(const Request& r);

struct Reply {
  uint8_t function = 0;  // without the exception bit
  bool exception = false;
  uint8_t exception_code = 0;
  uint16_t byte_count = 0;  // as sent: FC 01-04, 0C, 11, 14, 15 (data length), 17, 18 (2 bytes)
  uint16_t address = 0;     // echo: FC 05, 06, 0F, 10, 16
  uint16_t value = 0;       // echo: FC 05, 06
  uint16_t quantity = 0;    // echo: FC 0F, 10
  uint16_t and_mask = 0, or_mask = 0;  // echo: FC 16
  uint16_t sub_function = 0;           // FC 08
  uint8_t status = 0;                  // FC 07: the eight exception status outputs
  uint16_t status_word = 0;            // FC 0B, 0C
  uint16_t event_count = 0;            // FC 0B, 0C
  uint16_t message_count = 0;          // FC 0C
  std::vector<bool> bits{};              // FC 01, 02: every bit of the data bytes, padding included
  std::vector<uint16_t> registers{};     // FC 03, 04, 17; FC 18: the FIFO values
  Bytes data{};  // FC 08: data; 0C: events; 11: server id, run status, additional data; 2B other MEI
  std::vector<FileRecord> files{};  // FC 14, 15
  uint8_t mei_type = 0;           // FC 2B
  uint8_t read_device_id_code = 0, conformity_level = 0, more_follows = 0, next_object_id = 0;  // MEI 0E
  std::vector<DeviceIdObject> objects{};                                                          // MEI 0E
};

struct ParsedReply {
  std::optional<Reply> reply;
  std::string error;
  bool ok() const { return reply.has_value(); }
};
// The layout alone; judge.h judges a reply against its request.
ParsedReply parse_reply(std::span<const uint8_t> pdu);
Bytes build_reply(const Reply& r);
// The objects of a Read Device Identification reply (FC 2B / MEI 0E, §6.21)
// by id, as text (00 VendorName, 01 ProductCode, 02 Revision); empty when
// `pdu` is not a well-formed one.
std::map<int, std::string> device_identification(std::span<const uint8_t> pdu);

// ---- named request builders (counts computed) ----
Bytes read_request(uint8_t fc, uint16_t address, uint16_t quantity);  // FC 01-04
Bytes write_single_coil(uint16_t address, bool on);                    // FC 05
Bytes write_single_register(uint16_t address, uint16_t value);         // FC 06
Bytes diagnostics_request(uint16_t sub_function, uint16_t data);       // FC 08
Bytes write_multiple_coils(uint16_t address, std::span<const bool> values);          // FC 15
Bytes write_multiple_registers(uint16_t address, std::span<const uint16_t> values);  // FC 16
Bytes mask_write_register(uint16_t address, uint16_t and_mask, uint16_t or_mask);    // FC 22
Bytes read_write_registers(uint16_t read_address, uint16_t read_quantity, uint16_t write_address,
                           std::span<const uint16_t> values);  // FC 23
Bytes read_device_identification(uint8_t read_device_id_code, uint8_t object_id);  // FC 43 / MEI 14

// ---- named reply builders ----
Bytes exception_reply(uint8_t function, uint8_t code);                        // §7
Bytes read_bits_reply(uint8_t fc, std::span<const bool> bits);                // FC 01, 02 (padding zero)
Bytes read_registers_reply(uint8_t fc, std::span<const uint16_t> registers);  // FC 03, 04, 23

}  // namespace mbc
