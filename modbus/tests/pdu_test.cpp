// PDU parse and build against the example frames MBAP v1.1b3 §6 prints for
// each function code (request and response tables), and the errors a
// malformed PDU gets.
#include <gtest/gtest.h>

#include "modbus/function_codes.h"
#include "modbus/pdu.h"
#include "test_util.h"

namespace mbc {
namespace {

using test::hex;

struct Example {
  const char* section;
  const char* request;
  const char* reply;
};

// The standard's own example of each function code: request and response.
const Example kExamples[] = {
    {"6.1", "01 00 13 00 13", "01 03 CD 6B 05"},
    {"6.2", "02 00 C4 00 16", "02 03 AC DB 35"},
    {"6.3", "03 00 6B 00 03", "03 06 02 2B 00 00 00 64"},
    {"6.4", "04 00 08 00 01", "04 02 00 0A"},
    {"6.5", "05 00 AC FF 00", "05 00 AC FF 00"},
    {"6.6", "06 00 01 00 03", "06 00 01 00 03"},
    {"6.7", "07", "07 6D"},
    {"6.8", "08 00 00 A5 37", "08 00 00 A5 37"},
    {"6.9", "0B", "0B FF FF 01 08"},
    {"6.10", "0C", "0C 08 00 00 01 08 01 21 20 00"},
    {"6.11", "0F 00 13 00 0A 02 CD 01", "0F 00 13 00 0A"},
    {"6.12", "10 00 01 00 02 04 00 0A 01 02", "10 00 01 00 02"},
    // §6.13's reply is device specific: modbus-standard.yaml's profile note
    // (byte count 0B, server id 4D, run indicator FF, "mbconform").
    {"6.13", "11", "11 0B 4D FF 6D 62 63 6F 6E 66 6F 72 6D"},
    {"6.14", "14 0E 06 00 04 00 01 00 02 06 00 03 00 09 00 02", "14 0C 05 06 0D FE 00 20 05 06 33 CD 00 40"},
    {"6.15", "15 0D 06 00 04 00 07 00 03 06 AF 04 BE 10 0D", "15 0D 06 00 04 00 07 00 03 06 AF 04 BE 10 0D"},
    {"6.16", "16 00 04 00 F2 00 25", "16 00 04 00 F2 00 25"},
    {"6.17", "17 00 03 00 06 00 0E 00 03 06 00 FF 00 FF 00 FF", "17 0C 00 FE 0A CD 00 01 00 03 00 0D 00 FF"},
    {"6.18", "18 04 DE", "18 00 06 00 02 01 B8 12 84"},
    // §6.21 with modbus-standard.yaml's objects: "mbconform", "modbus-standard", "1.0", conformity 81.
    {"6.21", "2B 0E 01 00",
     "2B 0E 01 81 00 00 03 00 09 6D 62 63 6F 6E 66 6F 72 6D 01 0F 6D 6F 64 62 75 73 2D 73 74 61 6E 64 61 72 64 02 03 "
     "31 2E 30"},
    {"7", "01 04 A1 00 01", "81 02"},
};

TEST(Pdu, EveryStandardExampleParsesAndBuildsBackByteForByte) {
  for (const Example& e : kExamples) {
    SCOPED_TRACE(e.section);
    Bytes req = hex(e.request), rep = hex(e.reply);
    ParsedRequest pq = parse_request(req);
    ASSERT_TRUE(pq.ok()) << pq.error << (pq.problems.empty() ? "" : pq.problems[0]);
    EXPECT_EQ(build_request(*pq.request), req);
    ParsedReply pr = parse_reply(rep);
    ASSERT_TRUE(pr.ok()) << pr.error;
    EXPECT_EQ(build_reply(*pr.reply), rep);
  }
}

// The decoded fields are the ones the standard's tables name.
TEST(Pdu, RequestFieldsAreTheStandardsTableValues) {
  auto q = [](const char* h) { return *parse_request(hex(h)).request; };
  Request r = q("03 00 6B 00 03");  // §6.3: registers 108-110
  EXPECT_EQ(r.function, fc::read_holding_registers);
  EXPECT_EQ(r.address, 0x006B);
  EXPECT_EQ(r.quantity, 3);
  r = q("05 00 AC FF 00");  // §6.5: coil 173 ON
  EXPECT_EQ(r.address, 0x00AC);
  EXPECT_EQ(r.value, 0xFF00);
  r = q("08 00 00 A5 37");  // §6.8: return query data
  EXPECT_EQ(r.sub_function, 0);
  EXPECT_EQ(r.data, hex("A5 37"));
  r = q("0F 00 13 00 0A 02 CD 01");  // §6.11: coils 20-29
  EXPECT_EQ(r.quantity, 10);
  EXPECT_EQ(r.byte_count, 2);
  EXPECT_EQ(r.coils, (std::vector<bool>{1, 0, 1, 1, 0, 0, 1, 1, 1, 0}));
  r = q("10 00 01 00 02 04 00 0A 01 02");  // §6.12: registers 2 and 3 = 000A, 0102
  EXPECT_EQ(r.registers, (std::vector<uint16_t>{0x000A, 0x0102}));
  r = q("14 0E 06 00 04 00 01 00 02 06 00 03 00 09 00 02");  // §6.14: two sub-requests
  ASSERT_EQ(r.files.size(), 2u);
  EXPECT_EQ(r.files[0].file, 4);
  EXPECT_EQ(r.files[0].record, 1);
  EXPECT_EQ(r.files[0].length, 2);
  EXPECT_EQ(r.files[1].file, 3);
  EXPECT_EQ(r.files[1].record, 9);
  r = q("15 0D 06 00 04 00 07 00 03 06 AF 04 BE 10 0D");  // §6.15
  ASSERT_EQ(r.files.size(), 1u);
  EXPECT_EQ(r.files[0].data, (std::vector<uint16_t>{0x06AF, 0x04BE, 0x100D}));
  r = q("16 00 04 00 F2 00 25");  // §6.16
  EXPECT_EQ(r.and_mask, 0x00F2);
  EXPECT_EQ(r.or_mask, 0x0025);
  r = q("17 00 03 00 06 00 0E 00 03 06 00 FF 00 FF 00 FF");  // §6.17
  EXPECT_EQ(r.address, 3);
  EXPECT_EQ(r.quantity, 6);
  EXPECT_EQ(r.write_address, 0x0E);
  EXPECT_EQ(r.write_quantity, 3);
  EXPECT_EQ(r.registers, (std::vector<uint16_t>{0xFF, 0xFF, 0xFF}));
  r = q("18 04 DE");  // §6.18
  EXPECT_EQ(r.address, 0x04DE);
  r = q("2B 0E 01 00");  // §6.21: basic stream from object 0
  EXPECT_EQ(r.mei_type, kMeiReadDeviceId);
  EXPECT_EQ(r.read_device_id_code, 1);
  EXPECT_EQ(r.object_id, 0);
}

TEST(Pdu, ReplyFieldsAreTheStandardsTableValues) {
  auto p = [](const char* h) { return *parse_reply(hex(h)).reply; };
  Reply r = p("03 06 02 2B 00 00 00 64");  // §6.3: 555, 0, 100
  EXPECT_EQ(r.registers, (std::vector<uint16_t>{555, 0, 100}));
  r = p("01 03 CD 6B 05");  // §6.1: coils 27-20 CD, 35-28 6B, 38-36 05
  ASSERT_EQ(r.bits.size(), 24u);
  EXPECT_EQ(std::vector<bool>(r.bits.begin(), r.bits.begin() + 8), (std::vector<bool>{1, 0, 1, 1, 0, 0, 1, 1}));
  r = p("07 6D");
  EXPECT_EQ(r.status, 0x6D);
  r = p("0B FF FF 01 08");  // §6.9: busy, 264 events
  EXPECT_EQ(r.status_word, 0xFFFF);
  EXPECT_EQ(r.event_count, 0x0108);
  r = p("0C 08 00 00 01 08 01 21 20 00");  // §6.10
  EXPECT_EQ(r.event_count, 0x0108);
  EXPECT_EQ(r.message_count, 0x0121);
  EXPECT_EQ(r.data, hex("20 00"));
  r = p("14 0C 05 06 0D FE 00 20 05 06 33 CD 00 40");  // §6.14
  ASSERT_EQ(r.files.size(), 2u);
  EXPECT_EQ(r.files[0].data, (std::vector<uint16_t>{0x0DFE, 0x0020}));
  EXPECT_EQ(r.files[1].data, (std::vector<uint16_t>{0x33CD, 0x0040}));
  r = p("18 00 06 00 02 01 B8 12 84");  // §6.18
  EXPECT_EQ(r.registers, (std::vector<uint16_t>{0x01B8, 0x1284}));
  r = p("81 02");
  EXPECT_TRUE(r.exception);
  EXPECT_EQ(r.function, fc::read_coils);
  EXPECT_EQ(r.exception_code, ex::illegal_data_address);
  r = p("2B 0E 01 81 00 00 01 00 03 31 2E 30");
  ASSERT_EQ(r.objects.size(), 1u);
  EXPECT_EQ(r.conformity_level, 0x81);
  EXPECT_EQ(r.objects[0].value, hex("31 2E 30"));
}

// The named builders give the standard's bytes.
TEST(Pdu, NamedBuildersGiveTheStandardsExamples) {
  EXPECT_EQ(read_request(3, 0x006B, 3), hex("03 00 6B 00 03"));
  EXPECT_EQ(write_single_coil(0x00AC, true), hex("05 00 AC FF 00"));
  EXPECT_EQ(write_single_register(1, 3), hex("06 00 01 00 03"));
  EXPECT_EQ(diagnostics_request(0, 0xA537), hex("08 00 00 A5 37"));
  const bool coils[] = {1, 0, 1, 1, 0, 0, 1, 1, 1, 0};
  EXPECT_EQ(write_multiple_coils(0x0013, coils), hex("0F 00 13 00 0A 02 CD 01"));
  const uint16_t regs[] = {0x000A, 0x0102};
  EXPECT_EQ(write_multiple_registers(1, regs), hex("10 00 01 00 02 04 00 0A 01 02"));
  EXPECT_EQ(mask_write_register(4, 0x00F2, 0x0025), hex("16 00 04 00 F2 00 25"));
  const uint16_t ff[] = {0xFF, 0xFF, 0xFF};
  EXPECT_EQ(read_write_registers(3, 6, 0x0E, ff), hex("17 00 03 00 06 00 0E 00 03 06 00 FF 00 FF 00 FF"));
  EXPECT_EQ(read_device_identification(1, 0), hex("2B 0E 01 00"));
  EXPECT_EQ(exception_reply(fc::read_coils, ex::illegal_data_address), hex("81 02"));
  const uint16_t values[] = {555, 0, 100};
  EXPECT_EQ(read_registers_reply(3, values), hex("03 06 02 2B 00 00 00 64"));
  // §6.1: coils 20..38; CD, 6B, then 3 bits of 05 with the padding zero.
  const bool bits[] = {1, 0, 1, 1, 0, 0, 1, 1, 1, 1, 0, 1, 0, 1, 1, 0, 1, 0, 1};
  EXPECT_EQ(read_bits_reply(1, bits), hex("01 03 CD 6B 05"));
}

struct Bad {
  const char* pdu;
  const char* error;  // a substring of the error
};

TEST(Pdu, MalformedRequestsGetAPreciseError) {
  for (const Bad& b : {
           Bad{"", "empty request PDU"},
           Bad{"03 00 6B 00", "FC03 request: 4 bytes, too short for the quantity at byte 3"},
           Bad{"03 00 6B 00 03 00", "FC03 request: 6 bytes, MBAP v1.1b3 §6 has 5"},
           Bad{"07 00", "FC07 request: 2 bytes, MBAP v1.1b3 §6 has 1"},
           Bad{"10 00 01 00 02 04 00 0A 01", "FC10 request: byte count 4 but 3 bytes follow"},
           Bad{"0F 00 13 00 0A", "too short for the byte count at byte 5"},
           Bad{"14 07 06 00 04 00 01 00", "byte count 7 but 6 bytes follow"},
           Bad{"15 07 06 00 04 00 07 00 03", "too short for the record data at byte 9"},
           Bad{"17 00 03 00 06 00 0E 00 03 06 00 FF", "write byte count 6 but 2 bytes follow"},
           Bad{"2B 0E 01", "too short for the object id at byte 3"},
           Bad{"83 00 00 00 01", "exception bit"},
       }) {
    ParsedRequest p = parse_request(hex(b.pdu));
    EXPECT_FALSE(p.request) << b.pdu;
    EXPECT_NE(p.error.find(b.error), std::string::npos) << b.pdu << ": " << p.error;
  }
}

TEST(Pdu, DecodableRequestsThatBreakARuleNameIt) {
  auto problems = [](const char* h) {
    ParsedRequest p = parse_request(hex(h));
    EXPECT_TRUE(p.request) << h << ": " << p.error;
    EXPECT_FALSE(p.ok()) << h;
    return p.problems.empty() ? std::string() : p.problems[0];
  };
  EXPECT_EQ(problems("10 00 01 00 02 02 00 0A"), "FC10 byte count 2 for 2 registers, MBAP v1.1b3 §6.12 needs 4");
  EXPECT_EQ(problems("0F 00 13 00 0A 01 CD"), "FC0F byte count 1 for 10 coils, MBAP v1.1b3 §6.11 needs 2");
  EXPECT_EQ(problems("05 00 AC 12 34"), "FC05 value 0x1234: MBAP v1.1b3 §6.5 allows 0xFF00 (on) and 0x0000 (off) only");
  EXPECT_EQ(problems("17 00 03 00 06 00 0E 00 03 02 00 FF"),
            "FC17 write byte count 2 for 3 registers, MBAP v1.1b3 §6.17 needs 6");
  EXPECT_EQ(problems("14 07 05 00 04 00 01 00 02"), "FC14 reference type 5: MBAP v1.1b3 §6.14 says 6");
  Bytes big{0x41};  // a user-defined code (MBAP §5): data kept as it is, but never over 253 bytes
  big.resize(254, 0);
  EXPECT_EQ(problems(to_hex(big).c_str()), "request PDU is 254 bytes, over the 253 of MBAP v1.1b3 §4.1");
}

// A request built with inconsistent counts on purpose parses back to the same fields.
TEST(Pdu, BuildWritesTheFieldsAsGiven) {
  Request r{.function = fc::write_multiple_registers, .address = 1, .quantity = 3, .byte_count = 4, .registers = {7, 8}};
  Bytes b = build_request(r);
  EXPECT_EQ(b, hex("10 00 01 00 03 04 00 07 00 08"));
  ParsedRequest p = parse_request(b);
  ASSERT_TRUE(p.request);
  EXPECT_EQ(p.request->quantity, 3);
  EXPECT_EQ(p.request->registers, (std::vector<uint16_t>{7, 8}));
  EXPECT_FALSE(p.ok());
}

TEST(Pdu, MalformedRepliesGetAPreciseError) {
  for (const Bad& b : {
           Bad{"", "empty reply PDU"},
           Bad{"81", "FC81 reply: 1 bytes, too short for the exception code at byte 1"},
           Bad{"81 02 00", "FC81 reply: 3 bytes, MBAP v1.1b3 §6 has 2"},
           Bad{"03 06 02 2B 00 00", "FC03 reply: byte count 6 but 4 bytes follow"},
           Bad{"03 03 00 00 00", "odd byte count 3"},
           Bad{"06 00 01 00", "too short for the value at byte 3"},
           Bad{"18 00 06 00 03 01 B8 12 84", "too short for the FIFO values"},
           Bad{"14 04 02 06 0D FE", "file response length 2"},
           Bad{"2B 0E 01 81 00 00 02 00 03 31 2E 30", "too short for the object id"},
       }) {
    ParsedReply p = parse_reply(hex(b.pdu));
    EXPECT_FALSE(p.reply) << b.pdu;
    EXPECT_NE(p.error.find(b.error), std::string::npos) << b.pdu << ": " << p.error;
  }
}

TEST(FunctionCodes, NamesFromTheStandard) {
  EXPECT_STREQ(function_name(0x03), "read holding registers");
  EXPECT_STREQ(function_name(0x17), "read/write multiple registers");
  EXPECT_STREQ(function_name(0x2B), "encapsulated interface transport");
  EXPECT_STREQ(function_name(0x41), "unknown function");
  EXPECT_STREQ(function_name(0x83), "unknown function");
  EXPECT_TRUE(is_standard_function(0x18));
  EXPECT_FALSE(is_standard_function(0x09));  // reserved (MBAP Annex A)
  EXPECT_STREQ(exception_name(0x02), "illegal data address");
  EXPECT_STREQ(exception_name(0x0B), "gateway target failed to respond");
  EXPECT_STREQ(exception_name(0x07), "non-standard");
}

// MBAP v1.1b3 §6.21: 2B 0E, read code 01, conformity 01, more 00, next 00,
// 3 objects, each id, length, text.
TEST(DeviceIdentification, ObjectsOfABasicStreamByIdAndNothingFromOtherReplies) {
  Bytes pdu{0x2B, 0x0E, 0x01, 0x01, 0x00, 0x00, 0x03, 0x00, 0x03, 'A', 'C', 'M', 0x01, 0x02, 'X', '1', 0x02, 0x03, '1', '.', '0'};
  auto objects = device_identification(pdu);
  ASSERT_EQ(objects.size(), 3u);
  EXPECT_EQ(objects[0], "ACM");
  EXPECT_EQ(objects[1], "X1");
  EXPECT_EQ(objects[2], "1.0");
  EXPECT_TRUE(device_identification(Bytes{0xAB, 0x01}).empty());  // exception 01
  EXPECT_TRUE(device_identification(Bytes{0x03, 0x02, 0x00, 0x01}).empty());
  Bytes cut(pdu.begin(), pdu.end() - 2);  // the last object's text cut short
  EXPECT_TRUE(device_identification(cut).empty());
}

}  // namespace
}  // namespace mbc
