#include "serve/endpoint.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <fmt/core.h>
#include <netdb.h>
#include <netinet/in.h>
#include <pty.h>
#include <sys/stat.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <stdexcept>

namespace mbc::serve {
namespace {

[[noreturn]] void fail(const std::string& what) {
  throw std::runtime_error(fmt::format("{}: {}", what, std::strerror(errno)));
}

}  // namespace

void set_nonblocking(int fd) {
  int flags = fcntl(fd, F_GETFL);
  if (flags < 0 || fcntl(fd, F_SETFL, flags | O_NONBLOCK) < 0) fail("fcntl");
  fcntl(fd, F_SETFD, FD_CLOEXEC);
}

std::string sockaddr_text(const sockaddr_storage& ss) {
  char host[INET6_ADDRSTRLEN] = "?";
  if (ss.ss_family == AF_INET) {
    auto* a = reinterpret_cast<const sockaddr_in*>(&ss);
    inet_ntop(AF_INET, &a->sin_addr, host, sizeof host);
    return fmt::format("{}:{}", host, ntohs(a->sin_port));
  }
  auto* a = reinterpret_cast<const sockaddr_in6*>(&ss);
  inet_ntop(AF_INET6, &a->sin6_addr, host, sizeof host);
  return fmt::format("[{}]:{}", host, ntohs(a->sin6_port));
}

TcpListener listen_tcp(const std::string& what, const std::string& host, uint16_t port, int backlog) {
  addrinfo hints{}, *res = nullptr;
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_PASSIVE | AI_NUMERICSERV;
  std::string p = std::to_string(port);
  if (int rc = getaddrinfo(host.c_str(), p.c_str(), &hints, &res); rc != 0)
    throw std::runtime_error(fmt::format("{} {}:{}: {}", what, host, port, gai_strerror(rc)));
  int fd = ::socket(res->ai_family, res->ai_socktype | SOCK_CLOEXEC, 0);
  int one = 1;
  if (fd >= 0) setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
  bool ok = fd >= 0 && ::bind(fd, res->ai_addr, res->ai_addrlen) == 0 && ::listen(fd, backlog) == 0;
  int err = errno;
  freeaddrinfo(res);
  if (!ok) {
    if (fd >= 0) ::close(fd);
    errno = err;
    fail(fmt::format("{} {}:{}", what, host, port));
  }
  set_nonblocking(fd);
  TcpListener l;
  l.fd = fd;
  sockaddr_storage ss{};
  socklen_t len = sizeof ss;
  getsockname(fd, reinterpret_cast<sockaddr*>(&ss), &len);
  l.bound = sockaddr_text(ss);
  l.port = ss.ss_family == AF_INET ? ntohs(reinterpret_cast<const sockaddr_in*>(&ss)->sin_port)
                                   : ntohs(reinterpret_cast<const sockaddr_in6*>(&ss)->sin6_port);
  return l;
}

RawPty open_raw_pty(const std::string& link) {
  RawPty p;
  if (openpty(&p.master, &p.slave, nullptr, nullptr, nullptr) != 0) fail("openpty");
  auto undo = [&](const std::string& what) {
    int err = errno;
    ::close(p.master);
    ::close(p.slave);
    errno = err;
    fail(what);
  };
  char name[256];
  if (ttyname_r(p.slave, name, sizeof name) != 0) undo("ttyname");
  p.name = name;
  termios t{};
  tcgetattr(p.slave, &t);
  cfmakeraw(&t);
  tcsetattr(p.slave, TCSANOW, &t);
  set_nonblocking(p.master);
  fcntl(p.slave, F_SETFD, FD_CLOEXEC);
  if (link.empty()) return p;
  struct stat st{};
  if (lstat(link.c_str(), &st) == 0) {
    if (!S_ISLNK(st.st_mode)) {
      ::close(p.master);
      ::close(p.slave);
      throw std::runtime_error(fmt::format("pty {}: exists and is not a symlink", link));
    }
    ::unlink(link.c_str());
  }
  if (symlink(name, link.c_str()) != 0) undo("pty symlink " + link);
  return p;
}

}  // namespace mbc::serve
