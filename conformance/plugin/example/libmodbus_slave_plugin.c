/*
 * An mbconform plugin around a real third-party slave stack: libmodbus's
 * modbus_reply(). It shows a vendor how little a plugin needs, and gives the
 * suite a stack it did not write to find deviations in.
 *
 * libmodbus answers through a file descriptor, so the instance owns an RTU
 * context whose socket (modbus_set_socket) is one end of a socketpair;
 * modbus_reply() writes the reply ADU there and handle_rtu() reads it from
 * the other end. The receive side of an RTU slave (CRC check, slave filter,
 * MB-SL v1.02 §2.5.1.2 and §2.2) is done here: libmodbus's modbus_receive()
 * would block on a truncated frame and, after a frame for another slave,
 * expects that slave's reply on the line and swallows the next request.
 *
 * Config (the target URI's config=): comma-separated, all optional:
 *   slave=N              the slave id (default 1)
 *   coils=START:COUNT    discrete=START:COUNT   holding=START:COUNT   input=START:COUNT
 * e.g. plugin:./libmbc_example_plugin.so?device=modbus-standard&config=slave=1,holding=0:256
 * Everything is volatile: power_cycle and reset clear the tables to 0.
 */
#include <errno.h>
#include <fcntl.h>
#include <modbus.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include "mbconform_plugin.h"

typedef struct {
  int start, count;
} table_t;

typedef struct {
  modbus_t* ctx;
  modbus_mapping_t* map;
  int fds[2]; /* [0]: libmodbus's socket, [1]: where the reply is read */
  int slave;
  table_t coils, discrete, holding, input;
  char error[160];
} instance_t;

/* MB-SL v1.02 Appendix B: CRC-16, polynomial 0xA001 reflected, initial 0xFFFF. */
static uint16_t crc16(const uint8_t* p, size_t n) {
  uint16_t crc = 0xFFFF;
  for (size_t i = 0; i < n; ++i) {
    crc ^= p[i];
    for (int b = 0; b < 8; ++b) crc = (crc & 1) ? (uint16_t)((crc >> 1) ^ 0xA001) : (uint16_t)(crc >> 1);
  }
  return crc;
}

static int parse_table(const char* value, table_t* t) {
  char* end = NULL;
  long start = strtol(value, &end, 10);
  if (end == value || *end != ':') return -1;
  const char* c = end + 1;
  long count = strtol(c, &end, 10);
  if (end == c || *end != '\0' || start < 0 || start > 0xFFFF || count < 0 || count > 0x10000 - start) return -1;
  t->start = (int)start;
  t->count = (int)count;
  return 0;
}

static int parse_config(instance_t* in, const char* config) {
  char buf[512];
  if (strlen(config) >= sizeof buf) {
    snprintf(in->error, sizeof in->error, "config longer than %zu characters", sizeof buf - 1);
    return -1;
  }
  strcpy(buf, config);
  char* save = NULL;
  for (char* item = strtok_r(buf, ",", &save); item; item = strtok_r(NULL, ",", &save)) {
    char* eq = strchr(item, '=');
    if (!eq) goto bad;
    *eq = '\0';
    const char* key = item;
    const char* value = eq + 1;
    if (strcmp(key, "slave") == 0) {
      char* end = NULL;
      long s = strtol(value, &end, 10);
      if (end == value || *end || s < 1 || s > 247) goto bad; /* MB-SL v1.02 §2.2 */
      in->slave = (int)s;
    } else if (strcmp(key, "coils") == 0) {
      if (parse_table(value, &in->coils)) goto bad;
    } else if (strcmp(key, "discrete") == 0) {
      if (parse_table(value, &in->discrete)) goto bad;
    } else if (strcmp(key, "holding") == 0) {
      if (parse_table(value, &in->holding)) goto bad;
    } else if (strcmp(key, "input") == 0) {
      if (parse_table(value, &in->input)) goto bad;
    } else {
      goto bad;
    }
    continue;
  bad:
    snprintf(in->error, sizeof in->error,
             "config item '%s': expected slave=N, coils=, discrete=, holding= or input=START:COUNT", item);
    return -1;
  }
  return 0;
}

static int new_mapping(instance_t* in) {
  if (in->map) modbus_mapping_free(in->map);
  in->map = modbus_mapping_new_start_address(in->coils.start, in->coils.count, in->discrete.start, in->discrete.count,
                                             in->holding.start, in->holding.count, in->input.start, in->input.count);
  return in->map ? 0 : -1;
}

static void example_destroy(void* p) {
  instance_t* in = p;
  if (!in) return;
  if (in->map) modbus_mapping_free(in->map);
  if (in->ctx) modbus_free(in->ctx); /* the socket is ours: closed below, never modbus_close'd */
  if (in->fds[0] >= 0) close(in->fds[0]);
  if (in->fds[1] >= 0) close(in->fds[1]);
  free(in);
}

static void* example_create(const char* config, char* error, size_t error_size) {
  instance_t* in = calloc(1, sizeof *in);
  if (!in) return NULL;
  in->fds[0] = in->fds[1] = -1;
  in->slave = 1;
  table_t all = {0, 256};
  in->coils = in->discrete = in->holding = in->input = all;
  if (parse_config(in, config ? config : "") != 0) goto fail;
  if (socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, in->fds) != 0) {
    snprintf(in->error, sizeof in->error, "socketpair: %s", strerror(errno));
    goto fail;
  }
  fcntl(in->fds[1], F_SETFL, O_NONBLOCK);
  /* The device name is never opened: the context only frames replies. */
  in->ctx = modbus_new_rtu("/dev/null", 19200, 'N', 8, 1);
  if (!in->ctx || modbus_set_slave(in->ctx, in->slave) != 0 || modbus_set_socket(in->ctx, in->fds[0]) != 0) {
    snprintf(in->error, sizeof in->error, "libmodbus context: %s", modbus_strerror(errno));
    goto fail;
  }
  /* modbus_reply sleeps the response timeout before an "illegal quantity"
   * exception (to let the line go quiet); 1 us is the least it accepts. */
  modbus_set_response_timeout(in->ctx, 0, 1);
  if (new_mapping(in) != 0) {
    snprintf(in->error, sizeof in->error, "modbus_mapping_new_start_address: %s", modbus_strerror(errno));
    goto fail;
  }
  return in;
fail:
  snprintf(error, error_size, "%s", in->error);
  example_destroy(in);
  return NULL;
}

static int example_handle_rtu(void* p, const uint8_t* request, size_t request_len, uint8_t* response,
                              size_t response_capacity) {
  instance_t* in = p;
  /* A frame shorter than address + function + CRC, longer than an RTU ADU,
   * with a wrong CRC or for another slave gets no reply (MB-SL §2.5.1.2, §2.2). */
  if (request_len < 4 || request_len > MBCONFORM_MAX_RTU_ADU) return 0;
  uint16_t crc = crc16(request, request_len - 2);
  if (request[request_len - 2] != (crc & 0xFF) || request[request_len - 1] != (crc >> 8)) return 0;
  if (request[0] != in->slave && request[0] != MODBUS_BROADCAST_ADDRESS) return 0;
  /* modbus_reply reads fields at fixed offsets whatever the length: give it
   * a zero-padded copy so a short frame cannot make it read past the input. */
  uint8_t req[MBCONFORM_MAX_RTU_ADU + 512];
  memset(req, 0, sizeof req);
  memcpy(req, request, request_len);
  if (modbus_reply(in->ctx, req, (int)request_len, in->map) < 0 && errno != ENOPROTOOPT) {
    snprintf(in->error, sizeof in->error, "modbus_reply: %s", modbus_strerror(errno));
    return -1;
  }
  ssize_t n = read(in->fds[1], response, response_capacity);
  if (n < 0) return (errno == EAGAIN || errno == EWOULDBLOCK) ? 0 : -1;
  uint8_t rest[256];
  while (read(in->fds[1], rest, sizeof rest) > 0) {
  }
  return (int)n;
}

static int example_reset(void* p) { return new_mapping(p); }

static const char* example_last_error(void* p) { return ((instance_t*)p)->error; }

static const mbconform_plugin_api_v1 api = {
    .abi_version = MBCONFORM_PLUGIN_ABI_VERSION,
    .struct_size = sizeof(mbconform_plugin_api_v1),
    .name = "libmodbus " LIBMODBUS_VERSION_STRING " modbus_reply",
    .create = example_create,
    .destroy = example_destroy,
    .handle_rtu = example_handle_rtu,
    .handle_pdu = NULL,
    .reset = example_reset,
    .power_cycle = example_reset, /* every table is volatile */
    .advance_time_us = NULL,      /* libmodbus has no time of its own */
    .last_error = example_last_error,
};

MBCONFORM_PLUGIN_EXPORT const mbconform_plugin_api_v1* mbconform_plugin_v1(void) { return &api; }
