#include "client/model.h"

#include <cstdio>
#include <map>
#include <memory>
#include <stdexcept>
#include <vector>

#include "modbus/function_codes.h"

namespace mbc::client::model {
namespace {

using nlohmann::json;

uint16_t u16(const json& op, const char* key) { return op.value(key, json(0)).get<uint16_t>(); }

std::vector<uint16_t> words_of(const json& op) {
  std::vector<uint16_t> w;
  for (const auto& v : op.value("values", json::array())) w.push_back(v.get<uint16_t>());
  return w;
}

std::vector<bool> bits_of(const json& op) {
  std::vector<bool> b;
  for (const auto& v : op.value("values", json::array())) b.push_back(v.is_boolean() ? v.get<bool>() : v.get<int>() != 0);
  return b;
}

const std::vector<std::pair<uint8_t, const char*>>& basic_objects() {
  static const std::vector<std::pair<uint8_t, const char*>> o{{0x00, kVendor}, {0x01, kProduct}, {0x02, kRevision}};
  return o;
}

}  // namespace

uint16_t holding(uint16_t a, bool other) { return uint16_t((other ? 0xB000 : 0x1000) + a); }
uint16_t input(uint16_t a, bool other) { return uint16_t((other ? 0xC000 : 0x2000) + a); }
bool coil(uint16_t a, bool other) { return (a % 3 == 0) != other; }
bool discrete(uint16_t a, bool other) { return (a % 2 == 1) != other; }

uint8_t function_of(const std::string& op) {
  static const std::map<std::string, uint8_t> codes{
      {"read_coils", fc::read_coils},
      {"read_discrete_inputs", fc::read_discrete_inputs},
      {"read_holding_registers", fc::read_holding_registers},
      {"read_input_registers", fc::read_input_registers},
      {"write_single_coil", fc::write_single_coil},
      {"write_single_register", fc::write_single_register},
      {"write_multiple_coils", fc::write_multiple_coils},
      {"write_multiple_registers", fc::write_multiple_registers},
      {"mask_write_register", fc::mask_write_register},
      {"read_write_multiple_registers", fc::read_write_multiple_registers},
      {"read_device_identification", fc::encapsulated_interface},
  };
  auto it = codes.find(op);
  return it == codes.end() ? 0 : it->second;
}

Bytes expected_request(const json& op) {
  std::string name = op.at("op").get<std::string>();
  uint8_t f = function_of(name);
  uint16_t a = u16(op, "address");
  switch (f) {
    case fc::read_coils:
    case fc::read_discrete_inputs:
    case fc::read_holding_registers:
    case fc::read_input_registers: return read_request(f, a, u16(op, "count"));
    case fc::write_single_coil: return write_single_coil(a, op.at("value").get<bool>());
    case fc::write_single_register: return write_single_register(a, u16(op, "value"));
    case fc::write_multiple_coils: {
      auto b = bits_of(op);
      std::unique_ptr<bool[]> arr(new bool[b.size()]);
      for (size_t i = 0; i < b.size(); ++i) arr[i] = b[i];
      return write_multiple_coils(a, std::span<const bool>(arr.get(), b.size()));
    }
    case fc::write_multiple_registers: return write_multiple_registers(a, words_of(op));
    case fc::mask_write_register: return mask_write_register(a, u16(op, "and_mask"), u16(op, "or_mask"));
    case fc::read_write_multiple_registers:
      return read_write_registers(u16(op, "read_address"), u16(op, "read_count"), u16(op, "write_address"), words_of(op));
    case fc::encapsulated_interface: return read_device_identification(1, uint8_t(u16(op, "object_id")));
  }
  throw std::invalid_argument("unknown op " + name);
}

Bytes reply_to(const Request& r, bool other) {
  switch (r.function) {
    case fc::read_coils:
    case fc::read_discrete_inputs: {
      std::unique_ptr<bool[]> b(new bool[r.quantity]);
      for (uint16_t i = 0; i < r.quantity; ++i) {
        uint16_t at = uint16_t(r.address + i);
        b[i] = r.function == fc::read_coils ? coil(at, other) : discrete(at, other);
      }
      return read_bits_reply(r.function, std::span<const bool>(b.get(), r.quantity));
    }
    case fc::read_holding_registers:
    case fc::read_input_registers:
    case fc::read_write_multiple_registers: {
      std::vector<uint16_t> w;
      for (uint16_t i = 0; i < r.quantity; ++i) {
        uint16_t at = uint16_t(r.address + i);
        w.push_back(r.function == fc::read_input_registers ? input(at, other) : holding(at, other));
      }
      return read_registers_reply(r.function, w);
    }
    case fc::write_single_coil:
    case fc::write_single_register:
    case fc::write_multiple_coils:
    case fc::write_multiple_registers:
    case fc::mask_write_register: {
      Reply e;
      e.function = r.function;
      e.address = r.address;
      e.value = r.value;
      e.quantity = r.quantity;
      e.and_mask = r.and_mask;
      e.or_mask = r.or_mask;
      return build_reply(e);
    }
    case fc::encapsulated_interface: {
      if (r.mei_type != kMeiReadDeviceId) break;
      Reply e;
      e.function = r.function;
      e.mei_type = kMeiReadDeviceId;
      e.read_device_id_code = 1;
      e.conformity_level = 0x01;
      for (const auto& [id, text] : basic_objects()) {
        std::string s = text;
        if (other) s = "other-" + s;
        e.objects.push_back({id, Bytes(s.begin(), s.end())});
      }
      return build_reply(e);
    }
  }
  return exception_reply(r.function, ex::illegal_function);
}

json expected_values(const json& op, bool other) {
  std::string name = op.at("op").get<std::string>();
  uint8_t f = function_of(name);
  json v = json::array();
  switch (f) {
    case fc::read_coils:
    case fc::read_discrete_inputs: {
      uint16_t a = u16(op, "address");
      for (uint16_t i = 0; i < u16(op, "count"); ++i)
        v.push_back(f == fc::read_coils ? coil(uint16_t(a + i), other) : discrete(uint16_t(a + i), other));
      return v;
    }
    case fc::read_holding_registers:
    case fc::read_input_registers: {
      uint16_t a = u16(op, "address");
      for (uint16_t i = 0; i < u16(op, "count"); ++i)
        v.push_back(f == fc::read_input_registers ? input(uint16_t(a + i), other) : holding(uint16_t(a + i), other));
      return v;
    }
    case fc::read_write_multiple_registers: {
      uint16_t a = u16(op, "read_address");
      for (uint16_t i = 0; i < u16(op, "read_count"); ++i) v.push_back(holding(uint16_t(a + i), other));
      return v;
    }
    case fc::encapsulated_interface: {
      json objects = json::object();
      for (const auto& [id, text] : basic_objects()) {
        char key[8];
        std::snprintf(key, sizeof key, "0x%02X", id);
        objects[key] = other ? std::string("other-") + text : std::string(text);
      }
      return json{{"objects", objects}};
    }
  }
  return json();  // writes: no values to report
}

}  // namespace mbc::client::model
