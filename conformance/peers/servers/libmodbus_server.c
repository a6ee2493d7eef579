/* A libmodbus 3.1.6 Modbus TCP server as a library's own test server would be
 * written (libmodbus tests/unit-test-server.c, bandwidth-server-many-up.c):
 * modbus_mapping_new with 200 coils, discrete inputs, holding and input
 * registers, a select() loop over modbus_receive + modbus_reply, default
 * options (500 ms response timeout). The peer tests run `mbconform run` on it.
 * Usage: libmodbus_server PORT [--die-on FC | --wedge-on FC]
 *        libmodbus_server --rtu DEVICE BAUD
 *   (127.0.0.1; prints "listening PORT" when ready). --rtu serves Modbus RTU
 *   as unit 1 on a serial line (a pty: 8N1 at BAUD) the way libmodbus
 *   tests/unit-test-server.c does: modbus_new_rtu, modbus_connect, then
 *   modbus_receive + modbus_reply for ever (prints "listening DEVICE"). For the runner's tests
 *   of a target that goes away: --die-on exits when a request with that
 *   function code comes; --wedge-on stops reading that connection (it stays
 *   open, nothing more is answered on it; new connections are served). */
#include <errno.h>
#include <modbus.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <unistd.h>

enum { kItems = 200 };
enum { kMbapHeader = 7 }; /* MBAP: transaction, protocol, length, unit; the function code follows */

/* RTU on a serial line, unit 1. A frame libmodbus refuses (bad CRC, another
 * unit, too short) makes modbus_receive return -1 or 0: the library has
 * already flushed or ignored it, and the loop waits for the next one. */
static int serve_rtu(const char* device, int baud, modbus_mapping_t* map) {
  modbus_t* ctx = modbus_new_rtu(device, baud, 'N', 8, 1);
  if (!ctx || modbus_set_slave(ctx, 1) < 0 || modbus_connect(ctx) < 0) {
    fprintf(stderr, "libmodbus: %s: %s\n", device, modbus_strerror(errno));
    return 1;
  }
  printf("listening %s\n", device);
  fflush(stdout);
  uint8_t query[MODBUS_RTU_MAX_ADU_LENGTH];
  for (;;) {
    int rc = modbus_receive(ctx, query);
    if (rc > 0) modbus_reply(ctx, query, rc, map);
  }
}

int main(int argc, char** argv) {
  int die_on = -1, wedge_on = -1;
  if (argc == 4 && strcmp(argv[1], "--rtu") == 0) {
    modbus_mapping_t* map = modbus_mapping_new(kItems, kItems, kItems, kItems);
    return map ? serve_rtu(argv[2], atoi(argv[3]), map) : 1;
  }
  if (argc == 4 && strcmp(argv[2], "--die-on") == 0) die_on = atoi(argv[3]);
  else if (argc == 4 && strcmp(argv[2], "--wedge-on") == 0) wedge_on = atoi(argv[3]);
  else if (argc != 2) {
    fprintf(stderr, "usage: %s PORT [--die-on FC | --wedge-on FC] | --rtu DEVICE BAUD\n", argv[0]);
    return 2;
  }
  signal(SIGPIPE, SIG_IGN);
  modbus_t* ctx = modbus_new_tcp("127.0.0.1", atoi(argv[1]));
  modbus_mapping_t* map = modbus_mapping_new(kItems, kItems, kItems, kItems);
  if (!ctx || !map) {
    fprintf(stderr, "libmodbus: %s\n", modbus_strerror(errno));
    return 1;
  }
  int server = modbus_tcp_listen(ctx, 8);
  if (server < 0) {
    fprintf(stderr, "listen: %s\n", modbus_strerror(errno));
    return 1;
  }
  printf("listening %s\n", argv[1]);
  fflush(stdout);
  fd_set all;
  FD_ZERO(&all);
  FD_SET(server, &all);
  int fdmax = server;
  uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];
  for (;;) {
    fd_set ready = all;
    if (select(fdmax + 1, &ready, NULL, NULL, NULL) < 0) {
      if (errno == EINTR) continue;
      return 1;
    }
    for (int fd = 0; fd <= fdmax; ++fd) {
      if (!FD_ISSET(fd, &ready)) continue;
      if (fd == server) {
        int c = accept(server, NULL, NULL);
        if (c >= 0) {
          FD_SET(c, &all);
          if (c > fdmax) fdmax = c;
        }
        continue;
      }
      modbus_set_socket(ctx, fd);
      int rc = modbus_receive(ctx, query);
      int fc = rc > kMbapHeader ? query[kMbapHeader] : -1;
      if (rc > 0 && fc == die_on) return 0;
      if (rc > 0 && fc == wedge_on) {
        FD_CLR(fd, &all);  /* open, never read again */
      } else if (rc > 0) {
        modbus_reply(ctx, query, rc, map);
      } else if (rc == -1) {
        close(fd);
        FD_CLR(fd, &all);
      }
    }
  }
}
