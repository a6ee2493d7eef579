// ref:<device-id>: the reference device in-process, behind the same RTU
// framing a serial master uses (so the ADU path, CRC and slave filtering are
// exercised), on a virtual clock the caller advances. `fault=NAME[,NAME]`
// serves a deliberately broken device (reference/faults/faults.h), the
// target that shows a case or property can fail. `reading=KEY` (tests) serves
// a device that takes the other reading of one contested fact
// (spec/loader/readings.h): no MUST case may fail against it.
#include <fmt/core.h>

#include <charconv>
#include <map>
#include <mutex>
#include <stdexcept>

#include "engine/device.h"
#include "faults/faults.h"
#include "loader.h"
#include "modbus/crc16.h"
#include "modbus/rtu.h"
#include "readings.h"
#include "targets/kinds.h"

namespace mbc::conf {
namespace {

int int_param(const Uri& u, const std::string& key, int fallback, int lo, int hi) {
  auto v = u.param(key);
  if (!v) return fallback;
  int n = 0;
  auto [end, ec] = std::from_chars(v->data(), v->data() + v->size(), n);
  if (ec != std::errc{} || end != v->data() + v->size() || n < lo || n > hi)
    throw std::invalid_argument(fmt::format("target parameter {}={}: expected an integer {}..{}", key, *v, lo, hi));
  return n;
}

// Property tests open a fresh ref: target per generated case: each spec is
// parsed and checked once per process.
spec::Spec cached_spec(const std::string& id) {
  static std::mutex mutex;
  static std::map<std::string, spec::Spec> cache;
  std::lock_guard lock(mutex);
  auto it = cache.find(id);
  if (it == cache.end()) it = cache.emplace(id, spec::load_spec_by_id(id)).first;
  return it->second;
}

class RefTarget final : public Target {
 public:
  RefTarget(const Uri& u) {
    if (u.path.empty()) throw std::invalid_argument("ref: target needs a device id, e.g. ref:hsc60");
    spec::Spec s;
    try {
      s = cached_spec(u.path);
    } catch (const std::exception& e) {
      throw std::runtime_error(fmt::format("ref:{}: {}", u.path, e.what()));
    }
    int unit = int_param(u, "unit", s.serial.slave_default.value_or(1), 1, 247);
    info_.kind = TargetKind::ref;
    info_.framing = framing_of(info_.kind);
    info_.live = is_live(info_.kind);
    info_.unit = uint8_t(unit);
    info_.virtual_clock = true;
    info_.power_cycle = true;
    info_.raw = true;
    info_.baud = s.serial.baud_default;
    info_.device_id = s.device.id;
    faults::FaultSet faults;
    if (auto f = u.param("fault")) {
      try {
        faults = faults::parse_faults(*f);
      } catch (const std::invalid_argument& e) {
        throw std::invalid_argument(fmt::format("target parameter fault={}: {}", *f, e.what()));
      }
    }
    info_.uri = fmt::format("ref:{}?unit={}", s.device.id, unit);
    if (!faults.empty()) info_.uri += "&fault=" + faults.names();
    if (auto key = u.param("reading")) {
      spec::Variant v = spec::other_reading(s, *key);  // std::invalid_argument names the contested facts
      s = std::move(v.spec);
      answers_ = std::move(v.answers);
      info_.uri += "&reading=" + *key;
    }
    ref::Bus bus;
    bus.add(std::make_unique<ref::Device>(std::move(s), uint8_t(unit)));
    bus_ = faults::FaultyBus(std::move(bus), faults);
  }

  const TargetInfo& info() const override { return info_; }

  Reply transact(uint8_t unit, std::span<const uint8_t> pdu) override {
    return exchange(rtu_frame(unit, pdu), unit);
  }

  Reply send_raw(std::span<const uint8_t> bytes, std::optional<size_t> gap_after) override {
    // A gap inside a frame splits it in two for the receiver (MB-SL §2.5.1.1).
    if (gap_after && *gap_after < bytes.size()) {
      Reply first = exchange(Bytes(bytes.begin(), bytes.begin() + *gap_after), info_.unit);
      Reply second = exchange(Bytes(bytes.begin() + *gap_after, bytes.end()), info_.unit);
      second.request.assign(bytes.begin(), bytes.end());
      if (!first.silent()) return first;
      return second;
    }
    return exchange(Bytes(bytes.begin(), bytes.end()), bytes.empty() ? info_.unit : bytes[0]);
  }

  void advance(std::chrono::microseconds dt) override { bus_.advance(uint64_t(dt.count())); }
  void power_cycle() override {
    for (auto& d : bus_.devices()) d->power_cycle();
  }
  bool trip_fault() override {
    bool tripped = false;
    for (auto& d : bus_.devices()) tripped = d->trip_fault() || tripped;
    return tripped;
  }

  ref::Device& device() { return *bus_.devices().front(); }

 private:
  Reply exchange(Bytes adu, uint8_t slave) {
    Reply r;
    auto t0 = std::chrono::steady_clock::now();
    std::optional<Bytes> out = answer_otherwise(adu);
    if (!out) out = bus_.handle_rtu(adu);
    else if (out->empty()) out.reset();
    r.latency = std::chrono::duration_cast<std::chrono::microseconds>(std::chrono::steady_clock::now() - t0);
    r.request = std::move(adu);
    if (out) r.frame = std::move(*out);
    decode_rtu_reply(r, slave);
    return r;
  }

  // reading=: a printed frame the variant answers the other way (an empty
  // frame stands for no reply); nullopt leaves the request to the device.
  std::optional<Bytes> answer_otherwise(const Bytes& adu) const {
    if (answers_.empty()) return std::nullopt;
    Unframed u = rtu_unframe(adu);
    if (!u.ok() || u.unit != info_.unit) return std::nullopt;
    const Bytes& pdu = u.pdu;
    for (const auto& [req, reply] : answers_)
      if (req == pdu) return reply ? rtu_frame(info_.unit, *reply) : Bytes{};
    return std::nullopt;
  }

  TargetInfo info_;
  std::vector<std::pair<Bytes, std::optional<Bytes>>> answers_;
  faults::FaultyBus bus_;  // the correct device when no fault= was given
};

}  // namespace

std::unique_ptr<Target> make_ref_target(const Uri& u) { return std::make_unique<RefTarget>(u); }

}  // namespace mbc::conf
