#include "modbus/function_codes.h"

#include <cstddef>

namespace mbc {
namespace {

struct Named {
  uint8_t code;
  const char* name;
};

// MBAP v1.1b3 §6, in the order of its sections.
constexpr Named kFunctions[] = {
    {fc::read_coils, "read coils"},
    {fc::read_discrete_inputs, "read discrete inputs"},
    {fc::read_holding_registers, "read holding registers"},
    {fc::read_input_registers, "read input registers"},
    {fc::write_single_coil, "write single coil"},
    {fc::write_single_register, "write single register"},
    {fc::read_exception_status, "read exception status"},
    {fc::diagnostics, "diagnostics"},
    {fc::get_comm_event_counter, "get comm event counter"},
    {fc::get_comm_event_log, "get comm event log"},
    {fc::write_multiple_coils, "write multiple coils"},
    {fc::write_multiple_registers, "write multiple registers"},
    {fc::report_server_id, "report server id"},
    {fc::read_file_record, "read file record"},
    {fc::write_file_record, "write file record"},
    {fc::mask_write_register, "mask write register"},
    {fc::read_write_multiple_registers, "read/write multiple registers"},
    {fc::read_fifo_queue, "read FIFO queue"},
    {fc::encapsulated_interface, "encapsulated interface transport"},
};

// MBAP v1.1b3 §7.
constexpr Named kExceptions[] = {
    {ex::illegal_function, "illegal function"},
    {ex::illegal_data_address, "illegal data address"},
    {ex::illegal_data_value, "illegal data value"},
    {ex::server_device_failure, "server device failure"},
    {ex::acknowledge, "acknowledge"},
    {ex::server_device_busy, "server device busy"},
    {ex::memory_parity_error, "memory parity error"},
    {ex::gateway_path_unavailable, "gateway path unavailable"},
    {ex::gateway_target_failed, "gateway target failed to respond"},
};

template <size_t N>
const char* find(const Named (&table)[N], uint8_t code) {
  for (const Named& n : table)
    if (n.code == code) return n.name;
  return nullptr;
}

}  // namespace

const char* function_name(uint8_t code) {
  const char* n = find(kFunctions, code);
  return n ? n : "unknown function";
}

bool is_standard_function(uint8_t code) { return find(kFunctions, code) != nullptr; }

bool is_write_function(uint8_t code) {
  switch (code) {
    case fc::write_single_coil:
    case fc::write_single_register:
    case fc::write_multiple_coils:
    case fc::write_multiple_registers:
    case fc::mask_write_register:
    case fc::read_write_multiple_registers: return true;
    default: return false;
  }
}

const char* exception_name(uint8_t code) {
  const char* n = find(kExceptions, code);
  return n ? n : "non-standard";
}

}  // namespace mbc
