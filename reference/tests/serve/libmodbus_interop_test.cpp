// `mbconform serve` against libmodbus 3.1.6, a third-party master: Modbus TCP
// and RTU on the pty, every reference device, a two-device bus with
// broadcast, EEPROM persistence across restarts, clean shutdown, argument
// errors, concurrency and line-rate pacing. Register addresses, values and
// defaults come from the specs.
#include <arpa/inet.h>
#include <fcntl.h>
#include <modbus.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <memory>

#include <gtest/gtest.h>

#include "loader.h"
#include "modbus/crc16.h"
#include "modbus/hex.h"
#include "serve_process.h"
#include "spec_registers.h"

namespace mbc::serve_test {
namespace {

using namespace std::chrono_literals;
using spec::Register;

// A libmodbus context, connected; closed and freed on scope exit.
class Master {
 public:
  static Master tcp(int port) { return Master(modbus_new_tcp("127.0.0.1", port)); }
  static Master rtu(const std::string& path) { return Master(modbus_new_rtu(path.c_str(), 19200, 'N', 8, 1)); }

  Master(Master&& o) noexcept : ctx_(std::exchange(o.ctx_, nullptr)), connected_(o.connected_) {}
  ~Master() {
    if (!ctx_) return;
    if (connected_) modbus_close(ctx_);
    modbus_free(ctx_);
  }

  bool connected() const { return connected_; }
  modbus_t* ctx() { return ctx_; }
  void slave(int id) { modbus_set_slave(ctx_, id); }
  void timeout(std::chrono::milliseconds t) { modbus_set_response_timeout(ctx_, uint32_t(t.count() / 1000), uint32_t(t.count() % 1000 * 1000)); }

  // The word at `r` through the function code its table needs (FC 03 / FC 04).
  std::optional<uint16_t> read(const Register& r) { return read(r.address, r.table); }
  std::optional<uint16_t> read(uint16_t address, spec::Table table = spec::Table::holding) {
    uint16_t w = 0;
    int rc = table == spec::Table::input ? modbus_read_input_registers(ctx_, address, 1, &w)
                                         : modbus_read_registers(ctx_, address, 1, &w);
    if (rc != 1) return std::nullopt;
    return w;
  }
  bool write(uint16_t address, uint16_t value) { return modbus_write_register(ctx_, address, value) == 1; }
  std::string error() const { return modbus_strerror(errno); }

 private:
  explicit Master(modbus_t* ctx) : ctx_(ctx) {
    if (!ctx_) return;
    modbus_set_slave(ctx_, 1);
    timeout(1000ms);
    connected_ = modbus_connect(ctx_) == 0;
  }
  modbus_t* ctx_ = nullptr;
  bool connected_ = false;
};

// A raw TCP client for what no master library sends: half frames, pipelined
// requests, RTU frames over TCP. Reads time out after one second.
class RawClient {
 public:
  explicit RawClient(int port) : fd_(socket(AF_INET, SOCK_STREAM, 0)) {
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_port = htons(uint16_t(port));
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    connected_ = connect(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0;
    timeval tv{1, 0};
    setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  }
  ~RawClient() { close(fd_); }
  bool connected() const { return connected_; }
  bool send(std::span<const uint8_t> bytes) { return ::send(fd_, bytes.data(), bytes.size(), 0) == ssize_t(bytes.size()); }
  // Up to `n` bytes; fewer when the server stays silent for a second.
  Bytes receive(size_t n) {
    Bytes buf(n);
    size_t got = 0;
    while (got < n) {
      ssize_t k = recv(fd_, buf.data() + got, n - got, 0);
      if (k <= 0) break;
      got += size_t(k);
    }
    buf.resize(got);
    return buf;
  }

 private:
  int fd_;
  bool connected_ = false;
};

uint16_t default_word(const Register& r) { return uint16_t(int64_t(*r.default_value) & 0xFFFF); }

// ---- every reference device, on each transport ----

struct DeviceOnTransport {
  std::string device;
  std::string transport;  // tcp | pty
};
void PrintTo(const DeviceOnTransport& d, std::ostream* os) { *os << d.device << " on " << d.transport; }

std::vector<DeviceOnTransport> all_cases() {
  std::vector<DeviceOnTransport> v;
  for (const auto& id : spec::spec_ids())
    for (const char* t : {"tcp", "pty"}) v.push_back({id, t});
  return v;
}

class EachDevice : public ::testing::TestWithParam<DeviceOnTransport> {
 protected:
  void SetUp() override {
    spec_ = spec::load_spec_by_id(GetParam().device);
    server_ = std::make_unique<ServeProcess>(
        std::vector<std::string>{"--device", GetParam().device + "@1", "--tcp", "0", "--pty", dir_ / "tty"});
    ASSERT_TRUE(server_->wait_listening(2)) << server_->log();
  }
  void TearDown() override {
    if (server_) {
      EXPECT_EQ(server_->stop(SIGTERM), 0) << server_->log();
    }
  }
  Master master() {
    if (GetParam().transport == "tcp") return Master::tcp(server_->endpoint("tcp")->port());
    return Master::rtu(server_->endpoint("pty")->address);
  }

  TempDir dir_;
  spec::Spec spec_;
  std::unique_ptr<ServeProcess> server_;
};

TEST_P(EachDevice, WritesTheMiddleOfARangeAndReadsItBack) {
  const Register* r = pick_rw(spec_);
  if (!r) {
    GTEST_SKIP() << "no plain rw register with a range in " << spec_.device.id;
  }
  Master m = master();
  ASSERT_TRUE(m.connected()) << m.error();
  uint16_t value = middle_word(*r);
  ASSERT_TRUE(m.write(r->address, value)) << "write " << value << " to " << r->address << ": " << m.error() << "\n"
                                          << server_->log();
  EXPECT_EQ(m.read(*r), value) << "register " << r->address << ": " << m.error();
}

// Where the spec gives no range, the only value known to be valid is the one
// the register holds: write it back and read it again.
TEST_P(EachDevice, WritesBackARegistersOwnValue) {
  const Register* r = pick_rw_word(spec_);
  if (!r) {
    GTEST_SKIP() << "every rw word of " << spec_.device.id << " has a range";
  }
  Master m = master();
  ASSERT_TRUE(m.connected()) << m.error();
  auto value = m.read(*r);
  ASSERT_TRUE(value) << "register " << r->address << ": " << m.error();
  ASSERT_TRUE(m.write(r->address, *value)) << m.error() << "\n" << server_->log();
  EXPECT_EQ(m.read(*r), value) << "register " << r->address << ": " << m.error();
}

TEST_P(EachDevice, ReadsADefaultTheSpecStates) {
  const Register* r = pick_default_word(spec_);
  if (!r) {
    GTEST_SKIP() << "the spec states no default of a word in " << spec_.device.id;
  }
  Master m = master();
  ASSERT_TRUE(m.connected()) << m.error();
  EXPECT_EQ(m.read(*r), default_word(*r)) << "register " << r->address << ": " << m.error();
}

INSTANTIATE_TEST_SUITE_P(Serve, EachDevice, ::testing::ValuesIn(all_cases()),
                         [](const auto& info) {
                           std::string n = info.param.device + "_" + info.param.transport;
                           for (auto& c : n)
                             if (!isalnum(static_cast<unsigned char>(c))) c = '_';
                           return n;
                         });

// ---- several devices on one bus ----

// Two devices whose specs share a writable address: a broadcast write there
// must land in both (MB-SL v1.02 §2.1: every device accepts a broadcast write;
// none answers).
class TwoDeviceBus : public ::testing::Test {
 protected:
  void SetUp() override {
    a_ = spec::load_spec_by_id("sihong-57hs-r");
    b_ = spec::load_spec_by_id("modbus-standard");
    for (const auto& ra : a_.registers) {
      if (!plain_rw(a_, ra)) continue;
      const Register* rb = b_.find_register(ra.address);
      if (!rb || !plain_rw(b_, *rb)) continue;
      double lo = std::max(ra.range->min, rb->range->min), hi = std::min(ra.range->max, rb->range->max);
      if (lo >= hi || lo < 0) continue;
      address_ = ra.address;
      value_ = uint16_t((lo + hi) / 2);
      break;
    }
    ASSERT_TRUE(address_) << "the two specs share no writable address";
    server_ = std::make_unique<ServeProcess>(std::vector<std::string>{
        "--device", "sihong-57hs-r@1", "--device", "modbus-standard@2", "--tcp", "0", "--pty", dir_ / "tty"});
    ASSERT_TRUE(server_->wait_listening(2)) << server_->log();
  }
  void TearDown() override {
    if (server_) {
      EXPECT_EQ(server_->stop(SIGTERM), 0) << server_->log();
    }
  }
  void broadcast_then_read_back(Master m) {
    ASSERT_TRUE(m.connected()) << m.error();
    m.slave(0);
    m.timeout(300ms);
    // No reply comes to a broadcast; libmodbus may report a timeout. Either way the write is sent.
    m.write(*address_, value_);
    m.timeout(1000ms);
    for (int id : {1, 2}) {
      m.slave(id);
      EXPECT_EQ(m.read(*address_), value_) << "slave " << id << " register " << *address_ << ": " << m.error() << "\n"
                                           << server_->log();
    }
  }

  TempDir dir_;
  spec::Spec a_, b_;
  std::optional<uint16_t> address_;
  uint16_t value_ = 0;
  std::unique_ptr<ServeProcess> server_;
};

TEST_F(TwoDeviceBus, EachSlaveIdReachesItsOwnDevice) {
  Master m = Master::tcp(server_->endpoint("tcp")->port());
  ASSERT_TRUE(m.connected()) << m.error();
  const Register* ra = pick_default_word(a_);
  ASSERT_TRUE(ra);
  m.slave(1);
  EXPECT_EQ(m.read(*ra), default_word(*ra)) << m.error();
  // The same address on slave 2 is the other device's register.
  const Register* rb = b_.find_register(ra->address, ra->table);
  if (rb && rb->default_value && rb->access != spec::Access::wo) {
    m.slave(2);
    EXPECT_EQ(m.read(*rb), default_word(*rb)) << m.error();
  }
}

TEST_F(TwoDeviceBus, BroadcastOverRtuReachesBothDevices) { broadcast_then_read_back(Master::rtu(server_->endpoint("pty")->address)); }

TEST_F(TwoDeviceBus, BroadcastOverTcpUnitZeroReachesBothDevices) {
  broadcast_then_read_back(Master::tcp(server_->endpoint("tcp")->port()));
}

TEST_F(TwoDeviceBus, AFrameForAnAbsentSlaveGetsNoReply) {
  Master m = Master::rtu(server_->endpoint("pty")->address);
  ASSERT_TRUE(m.connected()) << m.error();
  m.slave(9);
  m.timeout(300ms);
  EXPECT_FALSE(m.read(*address_));
  EXPECT_EQ(errno, ETIMEDOUT) << m.error();
  // The line is still in step: the next request is answered.
  m.timeout(1000ms);
  m.slave(1);
  EXPECT_TRUE(m.read(*address_)) << m.error();
}

// A frame with a bad CRC is dropped (MB-SL v1.02 §2.4.2), then the line serves on.
TEST_F(TwoDeviceBus, ACorruptedRtuFrameIsDropped) {
  int fd = open(server_->endpoint("pty")->address.c_str(), O_RDWR | O_NOCTTY);
  ASSERT_GE(fd, 0);
  termios t{};
  tcgetattr(fd, &t);
  cfmakeraw(&t);
  t.c_cc[VMIN] = 0;
  t.c_cc[VTIME] = 3;  // 300 ms read timeout
  tcsetattr(fd, TCSANOW, &t);
  Bytes req{1, 0x03, uint8_t(*address_ >> 8), uint8_t(*address_), 0, 1};
  uint16_t crc = crc16(req);
  req.push_back(uint8_t(crc));
  req.push_back(uint8_t(crc >> 8));
  Bytes bad = req;
  bad.back() ^= 0xFF;
  ASSERT_EQ(write(fd, bad.data(), bad.size()), ssize_t(bad.size()));
  uint8_t buf[64];
  EXPECT_EQ(read(fd, buf, sizeof buf), 0) << "a reply came to a frame with a bad CRC";
  ASSERT_EQ(write(fd, req.data(), req.size()), ssize_t(req.size()));
  ssize_t n = read(fd, buf, sizeof buf);
  EXPECT_GE(n, 3);
  if (n >= 3) {
    EXPECT_EQ(buf[0], 1);
    EXPECT_EQ(buf[1], 0x03);
  }
  close(fd);
}

// ---- lifecycle ----

TEST(ServeLifecycle, SigtermAndSigintExitZeroAndRemoveThePtyLink) {
  for (int sig : {SIGTERM, SIGINT}) {
    TempDir dir;
    std::string tty = dir / "tty";
    ServeProcess server({"--device", "modbus-standard", "--pty", tty, "--rtu-tcp", "127.0.0.1:0"});
    ASSERT_TRUE(server.wait_listening(2)) << server.log();
    EXPECT_TRUE(std::filesystem::is_symlink(tty));
    EXPECT_EQ(server.stop(sig), 0) << "signal " << sig << "\n" << server.log();
    EXPECT_FALSE(std::filesystem::exists(std::filesystem::symlink_status(tty))) << tty;
  }
}

TEST(ServeLifecycle, PrintsOneListeningLinePerEndpointInOrder) {
  TempDir dir;
  ServeProcess server({"--device", "hsc60@3", "--tcp", "0", "--rtu-tcp", ":0", "--pty", dir / "tty", "--tcp", "127.0.0.1:0"});
  ASSERT_TRUE(server.wait_listening(4)) << server.log();
  const auto& e = server.endpoints();
  EXPECT_EQ(e[0].transport, "tcp");
  EXPECT_EQ(e[1].transport, "rtu-tcp");
  EXPECT_EQ(e[2].transport, "pty");
  EXPECT_EQ(e[2].address, dir / "tty");
  EXPECT_EQ(e[3].transport, "tcp");
  for (int i : {0, 1, 3}) {
    EXPECT_EQ(e[i].address.rfind("127.0.0.1:", 0), 0u) << e[i].address;
    EXPECT_GT(e[i].port(), 0) << "port 0 must be reported as the real port";
  }
  EXPECT_EQ(server.stop(SIGTERM), 0);
}

TEST(ServeLifecycle, BadArgumentsExitTwo) {
  TempDir dir;
  const std::vector<std::vector<std::string>> bad = {
      {"--tcp", "0"},                                      // no device
      {"--device", "modbus-standard"},                     // no endpoint
      {"--device", "no-such-device", "--tcp", "0"},        // unknown spec
      {"--device", "hsc60@0", "--tcp", "0"},               // slave 0 is broadcast
      {"--device", "hsc60@248", "--tcp", "0"},             // MB-SL §2.2: 248..255 reserved
      {"--device", "hsc60@1", "--device", "modbus-standard@1", "--tcp", "0"},  // two devices, one id
      {"--device", "hsc60", "--tcp", "70000"},             // no such port
      {"--device", "hsc60", "--tcp", "localhost:http"},    // not a port number
      {"--device", "hsc60", "--tcp", "0", "--baud", "0"},  // no such rate
      {"--device", "hsc60", "--pty", dir.path()},          // a directory, not a symlink
  };
  for (const auto& args : bad) {
    ServeProcess server(args);
    std::string cmd;
    for (const auto& a : args) cmd += a + " ";
    EXPECT_EQ(server.wait_exit(), 2) << cmd << "\n" << server.log();
    EXPECT_FALSE(server.log().empty()) << cmd << ": no message";
  }
}

// ---- EEPROM persistence ----

// A register the spec persists on write keeps its value across restarts;
// one that only a save command would keep returns to its default (a restart really happened).
TEST(ServeEeprom, PersistentRegistersSurviveRestarts) {
  std::string id;
  const Register* keep = nullptr;
  const Register* lose = nullptr;
  spec::Spec s;
  for (const auto& candidate : spec::spec_ids()) {
    s = spec::load_spec_by_id(candidate);
    keep = pick_persistent_on_write(s);
    lose = pick_lost_at_power_off(s);
    if (keep && lose) {
      id = candidate;
      break;
    }
  }
  if (id.empty()) {
    GTEST_SKIP() << "no spec has both a register persisted on write and one a power cycle resets";
  }
  TempDir dir;
  std::string eeprom = dir / "eeprom";
  std::vector<std::string> args{"--device", id + "@4", "--tcp", "0", "--eeprom", eeprom};
  uint16_t kept = word_other_than_default(*keep), lost = word_other_than_default(*lose);

  {  // saved on change: survives even a SIGKILL
    ServeProcess server(args);
    ASSERT_TRUE(server.wait_listening(1)) << server.log();
    Master m = Master::tcp(server.endpoint("tcp")->port());
    m.slave(4);
    ASSERT_TRUE(m.write(keep->address, kept)) << m.error() << "\n" << server.log();
    ASSERT_TRUE(m.write(lose->address, lost)) << m.error();
    EXPECT_TRUE(std::filesystem::exists(eeprom + "/" + id + "@4.json"));
    server.stop(SIGKILL);
  }
  {
    ServeProcess server(args);
    ASSERT_TRUE(server.wait_listening(1)) << server.log();
    Master m = Master::tcp(server.endpoint("tcp")->port());
    m.slave(4);
    EXPECT_EQ(m.read(*keep), kept) << "register " << keep->address << " after a restart";
    EXPECT_EQ(m.read(*lose), default_word(*lose)) << "unsaved register " << lose->address << " after a restart";
    // Back to the default, then a clean shutdown saves that too.
    ASSERT_TRUE(m.write(keep->address, default_word(*keep))) << m.error();
    EXPECT_EQ(server.stop(SIGTERM), 0) << server.log();
  }
  {
    ServeProcess server(args);
    ASSERT_TRUE(server.wait_listening(1)) << server.log();
    Master m = Master::tcp(server.endpoint("tcp")->port());
    m.slave(4);
    EXPECT_EQ(m.read(*keep), default_word(*keep));
    EXPECT_EQ(server.stop(SIGTERM), 0) << server.log();
  }
}

// ---- transports ----

// One client that sends half a request and stalls must not hold up another.
TEST(ServeTcp, AStalledClientDoesNotBlockOthers) {
  ServeProcess server({"--device", "modbus-standard", "--tcp", "0"});
  ASSERT_TRUE(server.wait_listening(1)) << server.log();
  int port = server.endpoint("tcp")->port();
  RawClient stalled(port);
  ASSERT_TRUE(stalled.connected());
  ASSERT_TRUE(stalled.send(Bytes{0x00, 0x01, 0x00, 0x00}));  // 4 of the 7 MBAP header bytes

  std::vector<Master> others;
  for (int i = 0; i < 5; ++i) others.push_back(Master::tcp(port));
  for (int round = 0; round < 3; ++round)
    for (auto& m : others) {
      ASSERT_TRUE(m.connected());
      m.timeout(500ms);
      EXPECT_TRUE(m.read(0)) << m.error();
    }
  EXPECT_EQ(server.stop(SIGTERM), 0);
}

// Modbus TCP echoes the request's transaction id (MB TCP v1.0b §3.1.3);
// two pipelined requests get two replies in order.
TEST(ServeTcp, RepliesCarryTheTransactionIdOfEachPipelinedRequest) {
  ServeProcess server({"--device", "modbus-standard", "--tcp", "0"});
  ASSERT_TRUE(server.wait_listening(1)) << server.log();
  RawClient c(server.endpoint("tcp")->port());
  ASSERT_TRUE(c.connected());
  ASSERT_TRUE(c.send(Bytes{0x12, 0x34, 0, 0, 0, 6, 1, 0x03, 0, 0, 0, 1,  //
                           0xAB, 0xCD, 0, 0, 0, 6, 1, 0x03, 0, 1, 0, 1}));
  // Each reply: MBAP (7) + FC + byte count + one word = 11 bytes.
  Bytes got = c.receive(22);
  ASSERT_EQ(got.size(), 22u) << server.log();
  EXPECT_EQ(got[0], 0x12);
  EXPECT_EQ(got[1], 0x34);
  EXPECT_EQ(got[5], 5);  // length: unit + 4 PDU bytes
  EXPECT_EQ(got[11], 0xAB);
  EXPECT_EQ(got[12], 0xCD);
  EXPECT_EQ(server.stop(SIGTERM), 0);
}

// RTU over TCP: one RTU ADU per request, CRC included (no MBAP).
TEST(ServeRtuTcp, AnswersAnRtuFrameWithAnRtuFrame) {
  spec::Spec s = spec::load_spec_by_id("hsc60");
  const Register* r = pick_default_word(s);
  ASSERT_TRUE(r);
  ServeProcess server({"--device", "hsc60@7", "--rtu-tcp", "0"});
  ASSERT_TRUE(server.wait_listening(1)) << server.log();
  RawClient c(server.endpoint("rtu-tcp")->port());
  ASSERT_TRUE(c.connected());
  uint8_t fc = r->table == spec::Table::input ? 0x04 : 0x03;
  Bytes req{7, fc, uint8_t(r->address >> 8), uint8_t(r->address), 0, 1};
  uint16_t crc = crc16(req);
  req.push_back(uint8_t(crc));
  req.push_back(uint8_t(crc >> 8));
  ASSERT_TRUE(c.send(req));
  Bytes got = c.receive(7);  // slave, FC, byte count, one word, CRC
  ASSERT_EQ(got.size(), 7u) << server.log();
  EXPECT_TRUE(crc_ok(got));
  EXPECT_EQ(got[0], 7);
  EXPECT_EQ(got[1], fc);
  EXPECT_EQ(got[2], 2);
  EXPECT_EQ(uint16_t(got[3] << 8 | got[4]), default_word(*r));
  EXPECT_EQ(server.stop(SIGTERM), 0);
}

// --line-rate 1200: a 7-byte reply takes (7 + 3.5) x 11 bits / 1200 baud = 96 ms
// (MB-SL v1.02 §2.5.1: 11 bits per character, t3.5 between frames).
TEST(ServeLineRate, RtuRepliesTakeTheirWireTime) {
  TempDir dir;
  ServeProcess server({"--device", "modbus-standard", "--pty", dir / "tty", "--line-rate", "1200"});
  ASSERT_TRUE(server.wait_listening(1)) << server.log();
  Master m = Master::rtu(server.endpoint("pty")->address);
  ASSERT_TRUE(m.connected()) << m.error();
  auto t0 = std::chrono::steady_clock::now();
  EXPECT_TRUE(m.read(0)) << m.error();
  auto took = std::chrono::steady_clock::now() - t0;
  EXPECT_GE(took, 90ms);
  EXPECT_EQ(server.stop(SIGTERM), 0);
}

TEST(ServeTrace, LogsEachFrameAsHexAndDecoded) {
  ServeProcess server({"--device", "modbus-standard@5", "--tcp", "0", "--trace"});
  ASSERT_TRUE(server.wait_listening(1)) << server.log();
  {
    Master m = Master::tcp(server.endpoint("tcp")->port());
    m.slave(5);
    ASSERT_TRUE(m.write(0x0002, 0x1234)) << m.error();
  }
  EXPECT_EQ(server.stop(SIGTERM), 0);
  std::string log = server.log();
  EXPECT_NE(log.find("05 06 00 02 12 34"), std::string::npos) << log;
  EXPECT_NE(log.find("unit 5 FC 06 write single register addr 0x0002 value 4660"), std::string::npos) << log;
}

}  // namespace
}  // namespace mbc::serve_test
