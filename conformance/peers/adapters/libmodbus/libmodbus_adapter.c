/* The libmodbus adapter of `mbconform client` (protocol 1, conformance/client/README.md).
 *
 * It reads one JSON object a line on stdin and answers one a line on stdout;
 * everything else goes to stderr. It drives libmodbus's own calls only: an op
 * libmodbus has no call for (FC 43 read device identification) is not listed
 * in "ops", and RTU over TCP, which libmodbus does not speak, is answered with
 * {"ready": false}.
 *
 *   libmodbus_adapter            (started by mbconform client --adapter ...)
 */
#include <errno.h>
#include <json-c/json.h>
#include <modbus.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define PROTOCOL 1

static modbus_t* ctx = NULL;

static void reply(json_object* o) {
  fputs(json_object_to_json_string_ext(o, JSON_C_TO_STRING_PLAIN), stdout);
  fputc('\n', stdout);
  fflush(stdout);
  json_object_put(o);
}

static json_object* answer(int id) {
  json_object* o = json_object_new_object();
  json_object_object_add(o, "id", json_object_new_int(id));
  return o;
}

static int get_int(json_object* o, const char* key, int fallback) {
  json_object* v;
  return json_object_object_get_ex(o, key, &v) ? json_object_get_int(v) : fallback;
}

static const char* get_str(json_object* o, const char* key, const char* fallback) {
  json_object* v;
  return json_object_object_get_ex(o, key, &v) ? json_object_get_string(v) : fallback;
}

/* The error a failed libmodbus call reports, in the protocol's words. */
static json_object* failure(int id, int err) {
  json_object* o = answer(id);
  json_object_object_add(o, "ok", json_object_new_boolean(0));
  const char* kind = "other";
  if (err > MODBUS_ENOBASE && err <= MODBUS_ENOBASE + 11) {
    kind = "exception";
    json_object_object_add(o, "code", json_object_new_int(err - MODBUS_ENOBASE));
  } else if (err == ETIMEDOUT) {
    kind = "timeout";
  } else if (err == EMBMDATA) {
    kind = "refused";
  } else if (err == EMBBADCRC || err == EMBBADDATA || err == EMBBADEXC || err == EMBUNKEXC || err == EMBBADSLAVE) {
    kind = "invalid_reply";
  }
  json_object_object_add(o, "error", json_object_new_string(kind));
  json_object_object_add(o, "detail", json_object_new_string(modbus_strerror(err)));
  return o;
}

static json_object* words(const uint16_t* w, int n) {
  json_object* a = json_object_new_array();
  for (int i = 0; i < n; i++) json_object_array_add(a, json_object_new_int(w[i]));
  return a;
}

static json_object* bits(const uint8_t* b, int n) {
  json_object* a = json_object_new_array();
  for (int i = 0; i < n; i++) json_object_array_add(a, json_object_new_boolean(b[i] != 0));
  return a;
}

static json_object* success(int id, json_object* values) {
  json_object* o = answer(id);
  json_object_object_add(o, "ok", json_object_new_boolean(1));
  json_object_object_add(o, "values", values ? values : json_object_new_array());
  return o;
}

/* Up to `max` integers of the request's `key` array; returns how many. */
static int int_array(json_object* req, const char* key, int* out, int max) {
  json_object* a;
  if (!json_object_object_get_ex(req, key, &a) || !json_object_is_type(a, json_type_array)) return 0;
  int n = (int)json_object_array_length(a);
  if (n > max) n = max;
  for (int i = 0; i < n; i++) out[i] = json_object_get_int(json_object_array_get_idx(a, i));
  return n;
}

#define MAX_ITEMS 4096 /* over every standard limit, so the library's own refusal is what is tested */

static json_object* do_op(int id, const char* op, json_object* req) {
  static uint16_t w[MAX_ITEMS];
  static uint8_t b[MAX_ITEMS];
  static int in[MAX_ITEMS];
  int addr = get_int(req, "address", 0), count = get_int(req, "count", 0), rc = -1;
  modbus_set_slave(ctx, get_int(req, "unit", 1));
  if (count > MAX_ITEMS) count = MAX_ITEMS;
  if (!strcmp(op, "read_coils") || !strcmp(op, "read_discrete_inputs")) {
    rc = (op[5] == 'c' ? modbus_read_bits : modbus_read_input_bits)(ctx, addr, count, b);
    return rc < 0 ? failure(id, errno) : success(id, bits(b, rc));
  }
  if (!strcmp(op, "read_holding_registers") || !strcmp(op, "read_input_registers")) {
    rc = (op[5] == 'h' ? modbus_read_registers : modbus_read_input_registers)(ctx, addr, count, w);
    return rc < 0 ? failure(id, errno) : success(id, words(w, rc));
  }
  if (!strcmp(op, "write_single_coil")) {
    json_object* v;
    int on = json_object_object_get_ex(req, "value", &v) && json_object_get_boolean(v);
    rc = modbus_write_bit(ctx, addr, on);
  } else if (!strcmp(op, "write_single_register")) {
    rc = modbus_write_register(ctx, addr, (uint16_t)get_int(req, "value", 0));
  } else if (!strcmp(op, "write_multiple_coils")) {
    int n = int_array(req, "values", in, MAX_ITEMS);
    for (int i = 0; i < n; i++) b[i] = (uint8_t)(in[i] != 0);
    rc = modbus_write_bits(ctx, addr, n, b);
  } else if (!strcmp(op, "write_multiple_registers")) {
    int n = int_array(req, "values", in, MAX_ITEMS);
    for (int i = 0; i < n; i++) w[i] = (uint16_t)in[i];
    rc = modbus_write_registers(ctx, addr, n, w);
  } else if (!strcmp(op, "mask_write_register")) {
    rc = modbus_mask_write_register(ctx, addr, (uint16_t)get_int(req, "and_mask", 0), (uint16_t)get_int(req, "or_mask", 0));
  } else if (!strcmp(op, "read_write_multiple_registers")) {
    static uint16_t r[MAX_ITEMS];
    int n = int_array(req, "values", in, MAX_ITEMS);
    for (int i = 0; i < n; i++) w[i] = (uint16_t)in[i];
    int rn = get_int(req, "read_count", 0);
    if (rn > MAX_ITEMS) rn = MAX_ITEMS;
    rc = modbus_write_and_read_registers(ctx, get_int(req, "write_address", 0), n, w, get_int(req, "read_address", 0), rn, r);
    return rc < 0 ? failure(id, errno) : success(id, words(r, rc));
  } else {
    json_object* o = answer(id);
    json_object_object_add(o, "ok", json_object_new_boolean(0));
    json_object_object_add(o, "error", json_object_new_string("unsupported"));
    return o;
  }
  return rc < 0 ? failure(id, errno) : success(id, NULL);
}

static json_object* hello(void) {
  static const char* ops[] = {"read_coils", "read_discrete_inputs", "read_holding_registers", "read_input_registers",
                              "write_single_coil", "write_single_register", "write_multiple_coils",
                              "write_multiple_registers", "mask_write_register", "read_write_multiple_registers"};
  json_object* o = json_object_new_object();
  json_object_object_add(o, "protocol", json_object_new_int(PROTOCOL));
  json_object_object_add(o, "library", json_object_new_string("libmodbus"));
  json_object_object_add(o, "version", json_object_new_string(LIBMODBUS_VERSION_STRING));
  json_object* a = json_object_new_array();
  for (size_t i = 0; i < sizeof ops / sizeof *ops; i++) json_object_array_add(a, json_object_new_string(ops[i]));
  json_object_object_add(o, "ops", a);
  json_object_object_add(o, "raw", json_object_new_boolean(0));
  /* libmodbus never retries a request on its own. */
  json_object_object_add(o, "retries", json_object_new_boolean(1));
  return o;
}

static json_object* not_ready(const char* fmt, ...) {
  char buf[256];
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(buf, sizeof buf, fmt, ap);
  va_end(ap);
  json_object* o = json_object_new_object();
  json_object_object_add(o, "ready", json_object_new_boolean(0));
  json_object_object_add(o, "detail", json_object_new_string(buf));
  return o;
}

static json_object* connect_to(json_object* c) {
  const char* transport = get_str(c, "transport", "");
  if (ctx) {
    modbus_close(ctx);
    modbus_free(ctx);
    ctx = NULL;
  }
  if (!strcmp(transport, "tcp")) {
    ctx = modbus_new_tcp(get_str(c, "host", "127.0.0.1"), get_int(c, "port", 502));
  } else if (!strcmp(transport, "rtu")) {
    const char* parity = get_str(c, "parity", "N");
    ctx = modbus_new_rtu(get_str(c, "device", ""), get_int(c, "baud", 9600), parity[0], get_int(c, "data", 8),
                         get_int(c, "stop", 1));
  } else {
    return not_ready("libmodbus has no %s transport", transport);
  }
  if (!ctx) return not_ready("modbus_new: %s", modbus_strerror(errno));
  int ms = get_int(c, "timeout_ms", 500);
  modbus_set_response_timeout(ctx, (uint32_t)(ms / 1000), (uint32_t)(ms % 1000) * 1000);
  modbus_set_byte_timeout(ctx, (uint32_t)(ms / 1000), (uint32_t)(ms % 1000) * 1000);
  if (modbus_connect(ctx) != 0) {
    json_object* o = not_ready("modbus_connect: %s", modbus_strerror(errno));
    modbus_free(ctx);
    ctx = NULL;
    return o;
  }
  json_object* o = json_object_new_object();
  json_object_object_add(o, "ready", json_object_new_boolean(1));
  return o;
}

int main(void) {
  /* libmodbus's debug output goes to stdout: keep stdout for the protocol. */
  char* line = NULL;
  size_t cap = 0;
  while (getline(&line, &cap, stdin) > 0) {
    json_object* req = json_tokener_parse(line);
    json_object* v;
    if (!req || !json_object_is_type(req, json_type_object)) {
      fprintf(stderr, "libmodbus adapter: not a JSON object: %s", line);
      json_object_put(req);
      continue;
    }
    if (json_object_object_get_ex(req, "hello", &v)) {
      reply(hello());
    } else if (json_object_object_get_ex(req, "connect", &v)) {
      reply(connect_to(v));
    } else if (json_object_object_get_ex(req, "disconnect", &v)) {
      if (ctx) {
        modbus_close(ctx);
        modbus_free(ctx);
        ctx = NULL;
      }
      json_object* o = json_object_new_object();
      json_object_object_add(o, "disconnected", json_object_new_boolean(1));
      reply(o);
    } else {
      const char* op = get_str(req, "op", "");
      if (!strcmp(op, "close")) {
        json_object_put(req);
        break;
      }
      int id = get_int(req, "id", 0);
      if (!ctx) {
        json_object* o = answer(id);
        json_object_object_add(o, "ok", json_object_new_boolean(0));
        json_object_object_add(o, "error", json_object_new_string("other"));
        json_object_object_add(o, "detail", json_object_new_string("not connected"));
        reply(o);
      } else {
        reply(do_op(id, op, req));
      }
    }
    json_object_put(req);
  }
  free(line);
  if (ctx) {
    modbus_close(ctx);
    modbus_free(ctx);
  }
  return 0;
}
