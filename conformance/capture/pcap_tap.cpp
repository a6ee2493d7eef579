#include "capture/pcap_tap.h"

#include <cerrno>
#include <chrono>
#include <cstring>
#include <algorithm>
#include <map>
#include <optional>
#include <stdexcept>

#include "modbus/pcapng.h"
#include "modbus/text.h"

namespace mbc::conf::capture {

uint64_t wall_clock_us() {
  return uint64_t(std::chrono::duration_cast<std::chrono::microseconds>(std::chrono::system_clock::now().time_since_epoch())
                      .count());
}

PcapFile::PcapFile(const std::string& path) : path_(path) {
  f_ = std::fopen(path.c_str(), "wb");
  if (!f_) throw std::runtime_error(strf("--pcap %s: %s", path.c_str(), std::strerror(errno)));
  write(pcapng::section_header("mbconform"));
}

PcapFile::~PcapFile() {
  if (f_) std::fclose(f_);
}

void PcapFile::write(std::span<const uint8_t> bytes) {
  std::fwrite(bytes.data(), 1, bytes.size(), f_);
  std::fflush(f_);  // a run that is killed still leaves a readable capture
}

uint32_t PcapFile::add_interface(uint16_t linktype, const std::string& name, const std::string& description) {
  std::lock_guard<std::mutex> lock(mu_);
  write(pcapng::interface_description(linktype, name, description));
  return interfaces_++;
}

void PcapFile::packet(uint32_t interface_id, uint64_t time_us, std::span<const uint8_t> data, int direction) {
  std::lock_guard<std::mutex> lock(mu_);
  write(pcapng::enhanced_packet(interface_id, time_us, data, direction));
}

constexpr uint32_t kClientIp = 0x0A000001;  // 10.0.0.1: mbconform (or the master under test)
constexpr uint32_t kServerIp = 0x0A000002;  // 10.0.0.2: the target (or the scenario server)
constexpr uint16_t kModbusPort = 502;       // what Wireshark's Modbus/TCP dissector listens on

namespace {

class TapTarget : public Target {
 public:
  TapTarget(std::unique_ptr<Target> inner, std::shared_ptr<PcapFile> file) : inner_(std::move(inner)), file_(std::move(file)) {
    const TargetInfo& i = inner_->info();
    mbap_ = i.framing == &mbc::kTcp;
    std::string what = strf("%s (%s)", i.uri.c_str(), mbap_ ? "Modbus TCP, drawn as 10.0.0.1 -> 10.0.0.2:502"
                                                              : "RTU ADUs; first byte: 0 to the device, 1 from it");
    iface_ = file_->add_interface(mbap_ ? pcapng::kLinkEthernet : pcapng::kLinkUser0, i.uri, what);
  }

  const TargetInfo& info() const override { return inner_->info(); }

  Reply transact(uint8_t unit, std::span<const uint8_t> pdu) override {
    uint64_t t0 = wall_clock_us();
    Reply r = inner_->transact(unit, pdu);
    record(t0, r);
    return r;
  }
  Reply send_raw(std::span<const uint8_t> bytes, std::optional<size_t> gap_after) override {
    uint64_t t0 = wall_clock_us();
    Reply r = inner_->send_raw(bytes, gap_after);
    record(t0, r);
    return r;
  }
  std::optional<std::chrono::microseconds> split_gap() const override { return inner_->split_gap(); }
  void set_split_gap(std::chrono::microseconds g) override { inner_->set_split_gap(g); }
  std::chrono::microseconds silence_window() const override { return inner_->silence_window(); }
  void set_wait(Wait w) override { inner_->set_wait(w); }
  uint64_t late_replies() const override { return inner_->late_replies(); }
  bool reconnect() override {
    bool ok = inner_->reconnect();
    if (ok && conv_) {
      uint64_t t = wall_clock_us();
      file_->packet(iface_, t, conv_->fin(true), 2);
      file_->packet(iface_, t, conv_->fin(false), 1);
      conv_.reset();
    }
    return ok;
  }
  void advance(std::chrono::microseconds dt) override { inner_->advance(dt); }
  void power_cycle() override { inner_->power_cycle(); }
  bool trip_fault() override { return inner_->trip_fault(); }

  ~TapTarget() override {
    if (conv_) {
      uint64_t t = wall_clock_us();
      file_->packet(iface_, t, conv_->fin(true), 2);
      file_->packet(iface_, t, conv_->fin(false), 1);
    }
  }

 private:
  void record(uint64_t t0, const Reply& r) {
    uint64_t t1 = t0 + uint64_t(std::max<int64_t>(0, r.latency.count()));
    if (mbap_) {
      if (!conv_) {
        conv_.emplace(kClientIp, uint16_t(40000 + (connections_++ % 20000)), kServerIp, kModbusPort);
        for (int step = 0; step < 3; ++step) file_->packet(iface_, t0, conv_->handshake(step), step == 1 ? 1 : 2);
      }
      if (!r.request.empty()) file_->packet(iface_, t0, conv_->data(true, r.request), 2);
      if (!r.frame.empty()) file_->packet(iface_, t1, conv_->data(false, r.frame), 1);
    } else {
      auto put = [&](uint64_t t, uint8_t dir, const Bytes& adu) {
        Bytes p;
        p.reserve(adu.size() + 1);
        p.push_back(dir);
        p.insert(p.end(), adu.begin(), adu.end());
        file_->packet(iface_, t, p, dir == 0 ? 2 : 1);
      };
      if (!r.request.empty()) put(t0, 0, r.request);
      if (!r.frame.empty()) put(t1, 1, r.frame);
    }
  }

  std::unique_ptr<Target> inner_;
  std::shared_ptr<PcapFile> file_;
  bool mbap_ = false;
  uint32_t iface_ = 0;
  std::optional<pcapng::TcpConversation> conv_;
  uint32_t connections_ = 0;
};

}  // namespace

std::unique_ptr<Target> tap(std::unique_ptr<Target> inner, std::shared_ptr<PcapFile> file) {
  return std::make_unique<TapTarget>(std::move(inner), std::move(file));
}

std::unique_ptr<Target> tap_pcap(std::unique_ptr<Target> inner, const std::string& path) {
  if (path.empty() || !inner) return inner;
  static std::mutex mu;
  static std::map<std::string, std::shared_ptr<PcapFile>> files;
  std::shared_ptr<PcapFile> f;
  {
    std::lock_guard<std::mutex> lock(mu);
    auto& slot = files[path];
    if (!slot) slot = std::make_shared<PcapFile>(path);
    f = slot;
  }
  return tap(std::move(inner), f);
}

std::function<void(std::vector<ClientFrame>)> client_pcap(const std::string& path, bool mbap, const std::string& name) {
  auto file = std::make_shared<PcapFile>(path);
  uint32_t iface = file->add_interface(mbap ? pcapng::kLinkEthernet : pcapng::kLinkUser0, name,
                                       mbap ? "Modbus TCP, drawn as 10.0.0.1 -> 10.0.0.2:502 (the master under test -> the scenario server)"
                                            : "RTU ADUs; first byte: 0 from the master, 1 from the scenario server");
  auto scenarios = std::make_shared<uint32_t>(0);
  return [file, iface, mbap, scenarios](std::vector<ClientFrame> frames) {
    std::stable_sort(frames.begin(), frames.end(),
                     [](const ClientFrame& a, const ClientFrame& b) { return std::get<0>(a) < std::get<0>(b); });
    // steady_clock to the wall clock: both read now.
    auto steady_now = std::chrono::steady_clock::now();
    uint64_t wall_now = wall_clock_us();
    auto wall = [&](std::chrono::steady_clock::time_point t) {
      auto back = std::chrono::duration_cast<std::chrono::microseconds>(steady_now - t).count();
      return wall_now - uint64_t(std::max<int64_t>(0, back));
    };
    if (frames.empty()) return;
    if (mbap) {
      pcapng::TcpConversation c(kClientIp, uint16_t(40000 + (*scenarios)++ % 20000), kServerIp, kModbusPort);
      uint64_t t0 = wall(std::get<0>(frames.front()));
      for (int step = 0; step < 3; ++step) file->packet(iface, t0, c.handshake(step), step == 1 ? 2 : 1);
      for (const auto& [t, from_master, bytes] : frames) file->packet(iface, wall(t), c.data(from_master, bytes), from_master ? 1 : 2);
      uint64_t t1 = wall(std::get<0>(frames.back()));
      file->packet(iface, t1, c.fin(true), 1);
      file->packet(iface, t1, c.fin(false), 2);
    } else {
      for (const auto& [t, from_master, bytes] : frames) {
        Bytes p;
        p.push_back(from_master ? 0 : 1);
        p.insert(p.end(), bytes.begin(), bytes.end());
        file->packet(iface, wall(t), p, from_master ? 1 : 2);
      }
    }
  };
}

}  // namespace mbc::conf::capture
