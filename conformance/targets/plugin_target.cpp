// plugin:PATH.so?device=ID&unit=N&config=...: a vendor's slave stack loaded
// with dlopen through the C ABI of conformance/plugin/mbconform_plugin.h.
// What the target can do follows the hooks the plugin fills in: handle_rtu
// gives raw frames, power_cycle a power cycle, advance_time_us a virtual clock.
#include <dlfcn.h>
#include <fmt/core.h>

#include <algorithm>
#include <stdexcept>

#include "loader.h"
#include "master/pdu.h"
#include "mbconform_plugin.h"
#include "targets/kinds.h"
#include "targets/live_link.h"

namespace mbc::conf {
namespace {

// The fields every version-1 plugin has, up to and including last_error.
constexpr size_t kV1Size = offsetof(mbconform_plugin_api_v1, last_error) + sizeof(void*);

class PluginTarget final : public Target {
 public:
  explicit PluginTarget(const Uri& u) {
    const std::string base = "plugin:" + u.path;
    live::check_params(u, base, {"device", "unit", "config"});
    if (u.path.empty())
      throw std::invalid_argument("target 'plugin:': needs the library's path, e.g. plugin:./libmystack.so");
    int default_unit = 1;
    if (auto id = u.param("device")) {
      try {
        default_unit = spec::load_spec_by_id(*id).serial.slave_default.value_or(1);
      } catch (const std::exception& e) {
        throw std::invalid_argument(fmt::format("target '{}': device={}: {}", base, *id, e.what()));
      }
      info_.device_id = *id;
    }
    int unit = live::int_param(u, base, "unit", default_unit, 1, 247);  // MB-SL v1.02 §2.2
    std::string config = u.param("config").value_or("");

    // A path without a slash would make dlopen search the library path.
    std::string path = u.path.find('/') == std::string::npos ? "./" + u.path : u.path;
    handle_ = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
    if (!handle_) throw std::runtime_error(fmt::format("target '{}': cannot load: {}", base, dlerror()));
    auto entry = reinterpret_cast<mbconform_plugin_entry_fn>(dlsym(handle_, MBCONFORM_PLUGIN_ENTRY));
    if (!entry) fail(fmt::format("target '{}': no {} symbol: not an mbconform plugin", base, MBCONFORM_PLUGIN_ENTRY));
    api_ = entry();
    if (!api_ || api_->abi_version != MBCONFORM_PLUGIN_ABI_VERSION || api_->struct_size < kV1Size)
      fail(fmt::format("target '{}': plugin ABI version {} (size {}), this host speaks version {}", base,
                       api_ ? api_->abi_version : 0, api_ ? api_->struct_size : 0, MBCONFORM_PLUGIN_ABI_VERSION));
    if (!api_->create || !api_->destroy || (!api_->handle_rtu && !api_->handle_pdu))
      fail(fmt::format("target '{}': the plugin lacks create, destroy or both handle hooks", base));
    char error[256] = "";
    instance_ = api_->create(config.c_str(), error, sizeof error);
    if (!instance_) fail(fmt::format("target '{}': the plugin refused config '{}': {}", base, config, error));

    info_.kind = "plugin";
    info_.framing = Framing::rtu;
    info_.unit = uint8_t(unit);
    info_.raw = api_->handle_rtu != nullptr;
    info_.power_cycle = api_->power_cycle != nullptr;
    info_.virtual_clock = api_->advance_time_us != nullptr;
    info_.implementation = api_->name ? api_->name : "";
    info_.uri = fmt::format("{}?{}unit={}{}", base, info_.device_id.empty() ? "" : "device=" + info_.device_id + "&",
                            unit, config.empty() ? "" : "&config=" + config);
  }

  ~PluginTarget() override {
    if (instance_) api_->destroy(instance_);
    if (handle_) dlclose(handle_);
  }

  const TargetInfo& info() const override { return info_; }

  Reply transact(uint8_t unit, std::span<const uint8_t> pdu) override {
    if (api_->handle_rtu) return exchange(rtu_frame(unit, pdu), unit);
    Reply r;
    r.request = rtu_frame(unit, pdu);
    uint8_t out[MBCONFORM_RESPONSE_CAPACITY];
    auto t0 = live::Clock::now();
    int n = api_->handle_pdu(instance_, unit, pdu.data(), pdu.size(), out, sizeof out);
    r.latency = std::chrono::duration_cast<std::chrono::microseconds>(live::Clock::now() - t0);
    check(n, "handle_pdu");
    if (n > 0) {
      r.frame = rtu_frame(unit, std::span(out, size_t(n)));  // framed here: the stack has no framing
      r.pdu = Bytes(out, out + n);
    }
    return r;
  }

  Reply send_raw(std::span<const uint8_t> bytes, std::optional<size_t> gap_after) override {
    if (!api_->handle_rtu) throw std::logic_error(info_.uri + ": the plugin has no handle_rtu: raw frames cannot be sent");
    // A gap inside a frame splits it in two for the receiver (MB-SL §2.5.1.1).
    if (gap_after && *gap_after < bytes.size()) {
      Reply first = exchange(Bytes(bytes.begin(), bytes.begin() + ptrdiff_t(*gap_after)), info_.unit);
      Reply second = exchange(Bytes(bytes.begin() + ptrdiff_t(*gap_after), bytes.end()), info_.unit);
      second.request.assign(bytes.begin(), bytes.end());
      return first.silent() ? second : first;
    }
    return exchange(Bytes(bytes.begin(), bytes.end()), bytes.empty() ? info_.unit : bytes[0]);
  }

  void advance(std::chrono::microseconds dt) override {
    if (!api_->advance_time_us) throw std::logic_error(info_.uri + ": the plugin has no advance_time_us");
    api_->advance_time_us(instance_, uint64_t(dt.count()));
  }

  void power_cycle() override {
    if (!api_->power_cycle) throw std::logic_error(info_.uri + ": the plugin has no power_cycle");
    check(api_->power_cycle(instance_), "power_cycle");
  }

 private:
  [[noreturn]] void fail(const std::string& what) {
    dlclose(handle_);
    handle_ = nullptr;
    throw std::runtime_error(what);
  }

  void check(int rc, const char* hook) const {
    if (rc >= 0) return;
    const char* why = api_->last_error ? api_->last_error(instance_) : nullptr;
    throw std::runtime_error(fmt::format("{}: {} failed: {}", info_.uri, hook, why && *why ? why : "no message"));
  }

  Reply exchange(Bytes adu, uint8_t slave) {
    Reply r;
    uint8_t out[MBCONFORM_RESPONSE_CAPACITY];
    auto t0 = live::Clock::now();
    int n = api_->handle_rtu(instance_, adu.data(), adu.size(), out, sizeof out);
    r.latency = std::chrono::duration_cast<std::chrono::microseconds>(live::Clock::now() - t0);
    r.request = std::move(adu);
    check(n, "handle_rtu");
    r.frame.assign(out, out + std::min<size_t>(size_t(n), sizeof out));
    decode_rtu_reply(r, slave);
    return r;
  }

  TargetInfo info_;
  void* handle_ = nullptr;
  const mbconform_plugin_api_v1* api_ = nullptr;
  void* instance_ = nullptr;
};

}  // namespace

std::unique_ptr<Target> make_plugin_target(const Uri& u) { return std::make_unique<PluginTarget>(u); }

}  // namespace mbc::conf
