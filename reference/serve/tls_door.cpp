#include "serve/tls_door.h"

#include <fcntl.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <stdexcept>

#include <fmt/core.h>

namespace mbc::serve {

TlsDoor::TlsDoor(const TlsOptions& o) : opt_(o), relay_(std::make_unique<tls::Relay>()) {
  if (o.files.cert.empty() || o.files.key.empty() || o.files.ca.empty())
    throw std::runtime_error("--tls needs --cert, --key and --ca (the CA that signs the client certificates)");
  tls::check_files(o.files, "--cert", "--key", "--ca");
  if (!o.roles_file.empty()) roles_ = tls::Roles::load(o.roles_file);
  if (pipe2(wake_, O_CLOEXEC | O_NONBLOCK) != 0) throw std::runtime_error(fmt::format("pipe: {}", std::strerror(errno)));
}

TlsDoor::~TlsDoor() {
  relay_.reset();  // its thread first: it calls back into this object
  for (auto& a : adopted_) ::close(a.fd);
  ::close(wake_[0]);
  ::close(wake_[1]);
}

std::string TlsDoor::listen(const std::string& host, uint16_t port) {
  auto bound = relay_->listen_tls(host, port, tls::server_context(opt_.files, roles_.has_value()), [this](const tls::Peer& p) {
    // A role the roles file does not name may do nothing: close at once.
    if (roles_ && (!p.role || !roles_->has(*p.role))) return -1;
    int sv[2];
    if (socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0, sv) != 0) return -1;
    Adopted a;
    a.fd = sv[0];
    a.name = fmt::format("tls {} {}{}", p.address, p.version, p.role ? " role " + *p.role : "");
    if (roles_) a.role = p.role;
    {
      std::lock_guard<std::mutex> g(mutex_);
      adopted_.push_back(std::move(a));
    }
    char c = 1;
    (void)!::write(wake_[1], &c, 1);
    return sv[1];
  });
  return "listening tls " + bound;
}

void TlsDoor::start() { relay_->start(); }

std::deque<TlsDoor::Adopted> TlsDoor::take() {
  char buf[64];
  while (::read(wake_[0], buf, sizeof buf) > 0) {
  }
  std::lock_guard<std::mutex> g(mutex_);
  std::deque<Adopted> out;
  out.swap(adopted_);
  return out;
}

std::string TlsDoor::refusal(const std::string& role, std::span<const uint8_t> pdu) const {
  return roles_ ? roles_->refusal(role, pdu) : "";
}

}  // namespace mbc::serve
