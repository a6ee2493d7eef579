// How every server of this project opens its end of a line: `mbconform
// serve` (TCP, RTU over TCP, a pty, the TLS door), the client's scenario
// servers and the mbtls:// relay. One way to listen, one way to make a pty
// that behaves like the serial port a master opens.
#pragma once

#include <sys/socket.h>

#include <cstdint>
#include <string>

namespace mbc::serve {

// O_NONBLOCK and FD_CLOEXEC on `fd`.
void set_nonblocking(int fd);

// "127.0.0.1:502", "[::1]:502".
std::string sockaddr_text(const sockaddr_storage& ss);

struct TcpListener {
  int fd = -1;         // listening, non-blocking, close-on-exec; the caller closes it
  std::string bound;   // the address it is bound to (sockaddr_text)
  uint16_t port = 0;   // the port bound (the one the system chose for port 0)
};
// A TCP socket listening on host:port (port 0: any free port; SO_REUSEADDR).
// Throws std::runtime_error "WHAT host:port: why" (WHAT: the caller's name
// for it, e.g. "tcp", "tls").
TcpListener listen_tcp(const std::string& what, const std::string& host, uint16_t port, int backlog = SOMAXCONN);

struct RawPty {
  int master = -1;   // non-blocking, close-on-exec: the server's end
  int slave = -1;    // close-on-exec; kept open so the line stays up between masters
  std::string name;  // /dev/pts/N
};
// A pty in raw mode, like a serial port a Modbus master opens (no echo, no
// line editing, no CR/LF translation, 8 data bits), and `link` (unless
// empty) a symlink to its slave. An existing symlink at `link` is replaced;
// anything else there is refused. Throws std::runtime_error naming what failed.
RawPty open_raw_pty(const std::string& link = "");

}  // namespace mbc::serve
