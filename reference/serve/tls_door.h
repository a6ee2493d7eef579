// `serve --tls`: the door through which Modbus/TCP Security connections
// enter serve's loop. The TLS relay (tls.h) runs the handshakes and the
// encryption in its own thread; each connection it lets in reaches the loop
// as one end of a socketpair, which the loop serves as a Modbus TCP link with
// the role of its client certificate. The loop learns of new links through
// wake_fd(), a descriptor it polls like a listener.
#pragma once

#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <string>

#include "serve/tls.h"

namespace mbc::serve {

struct TlsOptions {
  tls::Files files;        // --cert, --key, --ca
  std::string roles_file;  // --roles: empty, every role may do everything
};

class TlsDoor {
 public:
  // Checks the files and the roles file; throws std::runtime_error (one line).
  explicit TlsDoor(const TlsOptions& o);
  ~TlsDoor();
  // Opens a TLS listener; the "listening tls ADDR" line.
  std::string listen(const std::string& host, uint16_t port);
  void start();
  int wake_fd() const { return wake_[0]; }

  struct Adopted {
    int fd = -1;
    std::string name;                 // "tls 127.0.0.1:40112 role operator"
    std::optional<std::string> role;  // set when a roles file decides
  };
  // The connections let in since the last call (clears wake_fd()).
  std::deque<Adopted> take();
  // Empty when the role may send `pdu`; else why not.
  std::string refusal(const std::string& role, std::span<const uint8_t> pdu) const;

 private:
  std::optional<tls::Roles> roles_;
  TlsOptions opt_;
  int wake_[2] = {-1, -1};
  std::mutex mutex_;
  std::deque<Adopted> adopted_;
  std::unique_ptr<tls::Relay> relay_;  // its thread calls back into the members above
};

}  // namespace mbc::serve
