#include "modbus/pdu.h"

#include "modbus/function_codes.h"
#include "modbus/limits.h"
#include "modbus/text.h"

namespace mbc {
namespace {

// Reads fields off a PDU front to back; the first shortfall is the error.
class Reader {
 public:
  Reader(std::span<const uint8_t> pdu, const char* what) : p_(pdu), what_(what) {}

  bool need(size_t n, const char* field) {
    if (!error.empty()) return false;
    if (at_ + n <= p_.size()) return true;
    error = strf("FC%02X %s: %zu bytes, too short for the %s at byte %zu", p_[0], what_, p_.size(), field, at_);
    return false;
  }
  uint8_t u8(const char* field) { return need(1, field) ? p_[at_++] : 0; }
  uint16_t u16(const char* field) {
    if (!need(2, field)) return 0;
    at_ += 2;
    return be16(p_, at_ - 2);
  }
  std::vector<uint16_t> words(size_t n, const char* field) {
    std::vector<uint16_t> w;
    if (!need(2 * n, field)) return w;
    for (size_t i = 0; i < n; ++i) w.push_back(be16(p_, at_ + 2 * i));
    at_ += 2 * n;
    return w;
  }
  Bytes bytes(size_t n, const char* field) {
    if (!need(n, field)) return {};
    Bytes b(p_.begin() + ptrdiff_t(at_), p_.begin() + ptrdiff_t(at_ + n));
    at_ += n;
    return b;
  }
  Bytes rest() { return bytes(left(), "data"); }
  size_t left() const { return p_.size() - at_; }
  size_t at() const { return at_; }

  // The PDU must end here (§6 gives every request layout a fixed size or a byte count).
  bool end(const char* layout) {
    if (!error.empty()) return false;
    if (at_ == p_.size()) return true;
    error = strf("FC%02X %s: %zu bytes, MBAP v1.1b3 §6 has %zu (%s)", p_[0], what_, p_.size(), at_, layout);
    return false;
  }
  // A byte count that must equal what follows it.
  bool count_matches(size_t count, const char* field) {
    if (!error.empty()) return false;
    if (count == left()) return true;
    error = strf("FC%02X %s: %s %zu but %zu bytes follow", p_[0], what_, field, count, left());
    return false;
  }

  std::string error;

 private:
  std::span<const uint8_t> p_;
  const char* what_;
  size_t at_ = 1;
};

std::vector<bool> unpack_bits(std::span<const uint8_t> bytes, size_t n) {
  std::vector<bool> bits;
  for (size_t i = 0; i < n && i / 8 < bytes.size(); ++i) bits.push_back(bytes[i / 8] >> (i % 8) & 1);
  return bits;
}

void put_bits(Bytes& b, const std::vector<bool>& bits, size_t byte_count) {
  size_t at = b.size();
  b.resize(at + byte_count, 0);
  for (size_t i = 0; i < bits.size() && i / 8 < byte_count; ++i)
    if (bits[i]) b[at + i / 8] |= uint8_t(1u << (i % 8));
}

void put_words(Bytes& b, std::span<const uint16_t> words) {
  for (uint16_t w : words) put_be16(b, w);
}

// FC 20 request sub-requests: reference type, file, record, length (§6.14).
std::vector<FileRecord> file_requests(Reader& in, bool with_data) {
  std::vector<FileRecord> out;
  while (in.error.empty() && in.left() > 0) {
    FileRecord f;
    f.reference_type = in.u8("reference type");
    f.file = in.u16("file number");
    f.record = in.u16("record number");
    f.length = in.u16("record length");
    if (with_data) f.data = in.words(f.length, "record data");
    out.push_back(std::move(f));
  }
  return out;
}

void put_file_request(Bytes& b, const FileRecord& f, bool with_data) {
  b.push_back(f.reference_type);
  put_be16(b, f.file);
  put_be16(b, f.record);
  put_be16(b, f.length);
  if (with_data) put_words(b, f.data);
}

}  // namespace

ParsedRequest parse_request(std::span<const uint8_t> pdu) {
  ParsedRequest out;
  if (pdu.empty()) {
    out.error = "empty request PDU";
    return out;
  }
  Request r;
  r.function = pdu[0];
  if (r.function & kExceptionBit) {
    out.error = strf("FC%02X request: the exception bit is set (MBAP v1.1b3 §7), not a request", r.function);
    return out;
  }
  Reader in(pdu, "request");
  auto problem = [&](std::string s) { out.problems.push_back(std::move(s)); };
  switch (r.function) {
    case fc::read_coils:
    case fc::read_discrete_inputs:
    case fc::read_holding_registers:
    case fc::read_input_registers:
      r.address = in.u16("starting address");
      r.quantity = in.u16("quantity");
      in.end("address, quantity");
      break;
    case fc::write_single_coil:
    case fc::write_single_register:
      r.address = in.u16("address");
      r.value = in.u16("value");
      if (in.end("address, value") && r.function == fc::write_single_coil && r.value != 0xFF00 && r.value != 0x0000)
        problem(strf("FC05 value 0x%04X: MBAP v1.1b3 §6.5 allows 0xFF00 (on) and 0x0000 (off) only", r.value));
      break;
    case fc::read_exception_status:
    case fc::get_comm_event_counter:
    case fc::get_comm_event_log:
    case fc::report_server_id:
      in.end("function code only");
      break;
    case fc::diagnostics:
      r.sub_function = in.u16("sub-function");
      r.data = in.rest();
      if (in.error.empty() && r.data.size() % 2)
        problem(strf("FC08 data is %zu bytes, MBAP v1.1b3 §6.8 sends N x 2", r.data.size()));
      break;
    case fc::write_multiple_coils:
    case fc::write_multiple_registers: {
      bool coils = r.function == fc::write_multiple_coils;
      r.address = in.u16("starting address");
      r.quantity = in.u16("quantity");
      r.byte_count = in.u8("byte count");
      if (!in.count_matches(r.byte_count, "byte count")) break;
      Bytes values = in.rest();
      size_t want = coils ? (size_t(r.quantity) + 7) / 8 : 2 * size_t(r.quantity);
      if (coils) r.coils = unpack_bits(values, r.quantity);
      else
        for (size_t i = 0; i + 1 < values.size(); i += 2) r.registers.push_back(be16(values, i));
      if (r.byte_count != want)
        problem(strf("FC%02X byte count %u for %u %s, MBAP v1.1b3 §%s needs %zu", r.function, r.byte_count, r.quantity,
                     coils ? "coils" : "registers", coils ? "6.11" : "6.12", want));
      break;
    }
    case fc::read_file_record:
    case fc::write_file_record: {
      bool write = r.function == fc::write_file_record;
      r.byte_count = in.u8("byte count");
      if (!in.count_matches(r.byte_count, "byte count")) break;
      r.files = file_requests(in, write);
      for (const FileRecord& f : r.files)
        if (in.error.empty() && f.reference_type != 6)
          problem(strf("FC%02X reference type %u: MBAP v1.1b3 §%s says 6", r.function, f.reference_type,
                       write ? "6.15" : "6.14"));
      break;
    }
    case fc::mask_write_register:
      r.address = in.u16("reference address");
      r.and_mask = in.u16("AND mask");
      r.or_mask = in.u16("OR mask");
      in.end("address, AND mask, OR mask");
      break;
    case fc::read_write_multiple_registers: {
      r.address = in.u16("read starting address");
      r.quantity = in.u16("quantity to read");
      r.write_address = in.u16("write starting address");
      r.write_quantity = in.u16("quantity to write");
      r.byte_count = in.u8("write byte count");
      if (!in.count_matches(r.byte_count, "write byte count")) break;
      Bytes values = in.rest();
      for (size_t i = 0; i + 1 < values.size(); i += 2) r.registers.push_back(be16(values, i));
      if (r.byte_count != 2 * size_t(r.write_quantity))
        problem(strf("FC17 write byte count %u for %u registers, MBAP v1.1b3 §6.17 needs %u", r.byte_count,
                     r.write_quantity, 2 * unsigned(r.write_quantity)));
      break;
    }
    case fc::read_fifo_queue:
      r.address = in.u16("FIFO pointer address");
      in.end("FIFO pointer address");
      break;
    case fc::encapsulated_interface:
      r.mei_type = in.u8("MEI type");
      if (in.error.empty() && r.mei_type == kMeiReadDeviceId) {
        r.read_device_id_code = in.u8("read device id code");
        r.object_id = in.u8("object id");
        in.end("MEI type, read device id code, object id");
      } else {
        r.data = in.rest();
      }
      break;
    default:  // no layout in §6 (user-defined or reserved): the data as it is
      r.data = in.rest();
      break;
  }
  if (!in.error.empty()) {
    out.error = in.error;
    out.problems.clear();
    return out;
  }
  if (pdu.size() > kMaxPdu) problem(strf("request PDU is %zu bytes, over the 253 of MBAP v1.1b3 §4.1", pdu.size()));
  out.request = std::move(r);
  return out;
}

Bytes build_request(const Request& r) {
  Bytes b{r.function};
  switch (r.function) {
    case fc::read_coils:
    case fc::read_discrete_inputs:
    case fc::read_holding_registers:
    case fc::read_input_registers:
      put_be16(b, r.address);
      put_be16(b, r.quantity);
      break;
    case fc::write_single_coil:
    case fc::write_single_register:
      put_be16(b, r.address);
      put_be16(b, r.value);
      break;
    case fc::diagnostics:
      put_be16(b, r.sub_function);
      b.insert(b.end(), r.data.begin(), r.data.end());
      break;
    case fc::write_multiple_coils:
    case fc::write_multiple_registers:
      put_be16(b, r.address);
      put_be16(b, r.quantity);
      b.push_back(r.byte_count);
      if (r.function == fc::write_multiple_coils) put_bits(b, r.coils, r.byte_count);
      else put_words(b, r.registers);
      break;
    case fc::read_file_record:
    case fc::write_file_record:
      b.push_back(r.byte_count);
      for (const FileRecord& f : r.files) put_file_request(b, f, r.function == fc::write_file_record);
      break;
    case fc::mask_write_register:
      put_be16(b, r.address);
      put_be16(b, r.and_mask);
      put_be16(b, r.or_mask);
      break;
    case fc::read_write_multiple_registers:
      put_be16(b, r.address);
      put_be16(b, r.quantity);
      put_be16(b, r.write_address);
      put_be16(b, r.write_quantity);
      b.push_back(r.byte_count);
      put_words(b, r.registers);
      break;
    case fc::read_fifo_queue: put_be16(b, r.address); break;
    case fc::encapsulated_interface:
      b.push_back(r.mei_type);
      if (r.mei_type == kMeiReadDeviceId) {
        b.push_back(r.read_device_id_code);
        b.push_back(r.object_id);
      } else {
        b.insert(b.end(), r.data.begin(), r.data.end());
      }
      break;
    case fc::read_exception_status:
    case fc::get_comm_event_counter:
    case fc::get_comm_event_log:
    case fc::report_server_id: break;
    default: b.insert(b.end(), r.data.begin(), r.data.end()); break;
  }
  return b;
}

ParsedReply parse_reply(std::span<const uint8_t> pdu) {
  ParsedReply out;
  if (pdu.empty()) {
    out.error = "empty reply PDU";
    return out;
  }
  Reply r;
  r.function = uint8_t(pdu[0] & ~kExceptionBit);
  Reader in(pdu, "reply");
  if (pdu[0] & kExceptionBit) {
    r.exception = true;
    r.exception_code = in.u8("exception code");
    in.end("exception code, MBAP v1.1b3 §7");
  } else {
    switch (r.function) {
      case fc::read_coils:
      case fc::read_discrete_inputs: {
        r.byte_count = in.u8("byte count");
        if (!in.count_matches(r.byte_count, "byte count")) break;
        Bytes data = in.rest();
        r.bits = unpack_bits(data, 8 * data.size());
        break;
      }
      case fc::read_holding_registers:
      case fc::read_input_registers:
      case fc::read_write_multiple_registers:
        r.byte_count = in.u8("byte count");
        if (!in.count_matches(r.byte_count, "byte count")) break;
        if (r.byte_count % 2) {
          in.error = strf("FC%02X reply: odd byte count %u for 2-byte registers", r.function, r.byte_count);
          break;
        }
        r.registers = in.words(r.byte_count / 2, "register values");
        break;
      case fc::write_single_coil:
      case fc::write_single_register:
        r.address = in.u16("address");
        r.value = in.u16("value");
        in.end("echo of address, value");
        break;
      case fc::write_multiple_coils:
      case fc::write_multiple_registers:
        r.address = in.u16("starting address");
        r.quantity = in.u16("quantity");
        in.end("address, quantity");
        break;
      case fc::read_exception_status:
        r.status = in.u8("output data");
        in.end("output data");
        break;
      case fc::diagnostics:
        r.sub_function = in.u16("sub-function");
        r.data = in.rest();
        break;
      case fc::get_comm_event_counter:
        r.status_word = in.u16("status");
        r.event_count = in.u16("event count");
        in.end("status, event count");
        break;
      case fc::get_comm_event_log:
        r.byte_count = in.u8("byte count");
        if (!in.count_matches(r.byte_count, "byte count")) break;
        r.status_word = in.u16("status");
        r.event_count = in.u16("event count");
        r.message_count = in.u16("message count");
        r.data = in.rest();
        break;
      case fc::report_server_id:
        r.byte_count = in.u8("byte count");
        if (!in.count_matches(r.byte_count, "byte count")) break;
        r.data = in.rest();
        break;
      case fc::read_file_record:
        r.byte_count = in.u8("response data length");
        if (!in.count_matches(r.byte_count, "response data length")) break;
        while (in.error.empty() && in.left() > 0) {
          FileRecord f;
          uint8_t length = in.u8("file response length");
          f.reference_type = in.u8("reference type");
          if (in.error.empty() && (length < 1 || length % 2 == 0)) {
            in.error = strf("FC14 reply: file response length %u, MBAP v1.1b3 §6.14 has 1 + 2 x words", length);
            break;
          }
          f.data = in.words((length - 1u) / 2, "record data");
          f.length = uint16_t(f.data.size());
          r.files.push_back(std::move(f));
        }
        break;
      case fc::write_file_record:
        r.byte_count = in.u8("byte count");
        if (!in.count_matches(r.byte_count, "byte count")) break;
        r.files = file_requests(in, true);
        break;
      case fc::mask_write_register:
        r.address = in.u16("reference address");
        r.and_mask = in.u16("AND mask");
        r.or_mask = in.u16("OR mask");
        in.end("address, AND mask, OR mask");
        break;
      case fc::read_fifo_queue: {
        r.byte_count = in.u16("byte count");
        if (!in.count_matches(r.byte_count, "byte count")) break;
        uint16_t n = in.u16("FIFO count");
        r.registers = in.words(n, "FIFO values");
        in.end("FIFO count, FIFO values");
        break;
      }
      case fc::encapsulated_interface:
        r.mei_type = in.u8("MEI type");
        if (in.error.empty() && r.mei_type == kMeiReadDeviceId) {
          r.read_device_id_code = in.u8("read device id code");
          r.conformity_level = in.u8("conformity level");
          r.more_follows = in.u8("more follows");
          r.next_object_id = in.u8("next object id");
          uint8_t n = in.u8("number of objects");
          for (unsigned i = 0; i < n && in.error.empty(); ++i) {
            DeviceIdObject o;
            o.id = in.u8("object id");
            o.value = in.bytes(in.u8("object length"), "object value");
            r.objects.push_back(std::move(o));
          }
          in.end("objects as counted");
        } else {
          r.data = in.rest();
        }
        break;
      default: r.data = in.rest(); break;
    }
  }
  if (!in.error.empty()) {
    out.error = in.error;
    return out;
  }
  out.reply = std::move(r);
  return out;
}

Bytes build_reply(const Reply& r) {
  if (r.exception) return exception_reply(r.function, r.exception_code);
  Bytes b{r.function};
  switch (r.function) {
    case fc::read_coils:
    case fc::read_discrete_inputs:
      b.push_back(uint8_t(r.byte_count));
      put_bits(b, r.bits, r.byte_count);
      break;
    case fc::read_holding_registers:
    case fc::read_input_registers:
    case fc::read_write_multiple_registers:
      b.push_back(uint8_t(r.byte_count));
      put_words(b, r.registers);
      break;
    case fc::write_single_coil:
    case fc::write_single_register:
      put_be16(b, r.address);
      put_be16(b, r.value);
      break;
    case fc::write_multiple_coils:
    case fc::write_multiple_registers:
      put_be16(b, r.address);
      put_be16(b, r.quantity);
      break;
    case fc::read_exception_status: b.push_back(r.status); break;
    case fc::diagnostics:
      put_be16(b, r.sub_function);
      b.insert(b.end(), r.data.begin(), r.data.end());
      break;
    case fc::get_comm_event_counter:
      put_be16(b, r.status_word);
      put_be16(b, r.event_count);
      break;
    case fc::get_comm_event_log:
      b.push_back(uint8_t(r.byte_count));
      put_be16(b, r.status_word);
      put_be16(b, r.event_count);
      put_be16(b, r.message_count);
      b.insert(b.end(), r.data.begin(), r.data.end());
      break;
    case fc::read_file_record:
      b.push_back(uint8_t(r.byte_count));
      for (const FileRecord& f : r.files) {
        b.push_back(uint8_t(1 + 2 * f.data.size()));
        b.push_back(f.reference_type);
        put_words(b, f.data);
      }
      break;
    case fc::write_file_record:
      b.push_back(uint8_t(r.byte_count));
      for (const FileRecord& f : r.files) put_file_request(b, f, true);
      break;
    case fc::mask_write_register:
      put_be16(b, r.address);
      put_be16(b, r.and_mask);
      put_be16(b, r.or_mask);
      break;
    case fc::read_fifo_queue:
      put_be16(b, r.byte_count);
      put_be16(b, uint16_t(r.registers.size()));
      put_words(b, r.registers);
      break;
    case fc::encapsulated_interface:
      b.push_back(r.mei_type);
      if (r.mei_type == kMeiReadDeviceId) {
        for (uint8_t v : {r.read_device_id_code, r.conformity_level, r.more_follows, r.next_object_id,
                          uint8_t(r.objects.size())})
          b.push_back(v);
        for (const DeviceIdObject& o : r.objects) {
          b.push_back(o.id);
          b.push_back(uint8_t(o.value.size()));
          b.insert(b.end(), o.value.begin(), o.value.end());
        }
      } else {
        b.insert(b.end(), r.data.begin(), r.data.end());
      }
      break;
    case fc::report_server_id:
      b.push_back(uint8_t(r.byte_count));
      b.insert(b.end(), r.data.begin(), r.data.end());
      break;
    default: b.insert(b.end(), r.data.begin(), r.data.end()); break;
  }
  return b;
}

// ---- named builders ----

Bytes read_request(uint8_t fc, uint16_t address, uint16_t quantity) {
  return build_request({.function = fc, .address = address, .quantity = quantity});
}

Bytes write_single_coil(uint16_t address, bool on) {
  return build_request({.function = fc::write_single_coil, .address = address, .value = uint16_t(on ? 0xFF00 : 0x0000)});
}

Bytes write_single_register(uint16_t address, uint16_t value) {
  return build_request({.function = fc::write_single_register, .address = address, .value = value});
}

Bytes diagnostics_request(uint16_t sub_function, uint16_t data) {
  Request r{.function = fc::diagnostics, .sub_function = sub_function};
  put_be16(r.data, data);
  return build_request(r);
}

Bytes write_multiple_coils(uint16_t address, std::span<const bool> values) {
  return build_request({.function = fc::write_multiple_coils,
                        .address = address,
                        .quantity = uint16_t(values.size()),
                        .byte_count = uint8_t((values.size() + 7) / 8),
                        .coils = std::vector<bool>(values.begin(), values.end())});
}

Bytes write_multiple_registers(uint16_t address, std::span<const uint16_t> values) {
  return build_request({.function = fc::write_multiple_registers,
                        .address = address,
                        .quantity = uint16_t(values.size()),
                        .byte_count = uint8_t(values.size() * 2),
                        .registers = std::vector<uint16_t>(values.begin(), values.end())});
}

Bytes mask_write_register(uint16_t address, uint16_t and_mask, uint16_t or_mask) {
  return build_request({.function = fc::mask_write_register, .address = address, .and_mask = and_mask, .or_mask = or_mask});
}

Bytes read_write_registers(uint16_t read_address, uint16_t read_quantity, uint16_t write_address,
                           std::span<const uint16_t> values) {
  return build_request({.function = fc::read_write_multiple_registers,
                        .address = read_address,
                        .quantity = read_quantity,
                        .write_address = write_address,
                        .write_quantity = uint16_t(values.size()),
                        .byte_count = uint8_t(values.size() * 2),
                        .registers = std::vector<uint16_t>(values.begin(), values.end())});
}

std::map<int, std::string> device_identification(std::span<const uint8_t> pdu) {
  std::map<int, std::string> out;
  auto parsed = parse_reply(pdu);
  if (!parsed.ok() || parsed.reply->exception || parsed.reply->function != 0x2B || parsed.reply->mei_type != 0x0E) return out;
  for (const auto& o : parsed.reply->objects) out[o.id] = std::string(o.value.begin(), o.value.end());
  return out;
}

Bytes read_device_identification(uint8_t read_device_id_code, uint8_t object_id) {
  return build_request({.function = fc::encapsulated_interface,
                        .mei_type = kMeiReadDeviceId,
                        .read_device_id_code = read_device_id_code,
                        .object_id = object_id});
}

Bytes exception_reply(uint8_t function, uint8_t code) { return Bytes{uint8_t(function | kExceptionBit), code}; }

Bytes read_bits_reply(uint8_t fc, std::span<const bool> bits) {
  return build_reply({.function = fc,
                      .byte_count = uint16_t((bits.size() + 7) / 8),
                      .bits = std::vector<bool>(bits.begin(), bits.end())});
}

Bytes read_registers_reply(uint8_t fc, std::span<const uint16_t> registers) {
  return build_reply({.function = fc,
                      .byte_count = uint16_t(registers.size() * 2),
                      .registers = std::vector<uint16_t>(registers.begin(), registers.end())});
}

}  // namespace mbc
