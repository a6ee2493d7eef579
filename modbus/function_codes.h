// Function codes (MBAP v1.1b3 §5.1, §6) and exception codes (§7), with the
// standard's names: one table for the trace, the reports and the judge.
#pragma once

#include <cstdint>

namespace mbc {

namespace fc {
inline constexpr uint8_t read_coils = 0x01;                      // §6.1
inline constexpr uint8_t read_discrete_inputs = 0x02;            // §6.2
inline constexpr uint8_t read_holding_registers = 0x03;          // §6.3
inline constexpr uint8_t read_input_registers = 0x04;            // §6.4
inline constexpr uint8_t write_single_coil = 0x05;               // §6.5
inline constexpr uint8_t write_single_register = 0x06;           // §6.6
inline constexpr uint8_t read_exception_status = 0x07;           // §6.7 (serial line only)
inline constexpr uint8_t diagnostics = 0x08;                     // §6.8 (serial line only)
inline constexpr uint8_t get_comm_event_counter = 0x0B;          // §6.9 (serial line only)
inline constexpr uint8_t get_comm_event_log = 0x0C;              // §6.10 (serial line only)
inline constexpr uint8_t write_multiple_coils = 0x0F;            // §6.11
inline constexpr uint8_t write_multiple_registers = 0x10;        // §6.12
inline constexpr uint8_t report_server_id = 0x11;                // §6.13 (serial line only)
inline constexpr uint8_t read_file_record = 0x14;                // §6.14
inline constexpr uint8_t write_file_record = 0x15;               // §6.15
inline constexpr uint8_t mask_write_register = 0x16;             // §6.16
inline constexpr uint8_t read_write_multiple_registers = 0x17;   // §6.17
inline constexpr uint8_t read_fifo_queue = 0x18;                 // §6.18
inline constexpr uint8_t encapsulated_interface = 0x2B;          // §6.19-6.21
}  // namespace fc

// §6.21: MEI type 0x0E, Read Device Identification (0x0D is CANopen, §6.20).
inline constexpr uint8_t kMeiReadDeviceId = 0x0E;
// §7: an exception reply's function code is the request's with this bit set.
inline constexpr uint8_t kExceptionBit = 0x80;

namespace ex {
inline constexpr uint8_t illegal_function = 0x01;
inline constexpr uint8_t illegal_data_address = 0x02;
inline constexpr uint8_t illegal_data_value = 0x03;
inline constexpr uint8_t server_device_failure = 0x04;
inline constexpr uint8_t acknowledge = 0x05;
inline constexpr uint8_t server_device_busy = 0x06;
inline constexpr uint8_t memory_parity_error = 0x08;
inline constexpr uint8_t gateway_path_unavailable = 0x0A;
inline constexpr uint8_t gateway_target_failed = 0x0B;
}  // namespace ex

// The standard's name of `code`, in lower case: "read holding registers";
// "unknown function" for codes §6 does not define (an exception reply's code
// among them: mask kExceptionBit first).
const char* function_name(uint8_t code);
// True when §6 defines `code`.
bool is_standard_function(uint8_t code);
// True when a request of `code` changes the data model: FC 05, 06, 15, 16,
// 22, 23 (§6.5, §6.6, §6.11, §6.12, §6.16, §6.17). FC 21 writes file
// records, outside the four tables.
bool is_write_function(uint8_t code);
// §7's name of exception `code`: "illegal data address"; "non-standard" otherwise.
const char* exception_name(uint8_t code);

}  // namespace mbc
