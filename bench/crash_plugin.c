/* The plugin mbc_bench_plugin_restart crashes: a PDU stack that answers
 * FC 03 with zeros, everything else with exception 01, and dies by SIGSEGV
 * on a request with function code 0x41. */
#include <string.h>

#include "mbconform_plugin.h"

static int token;

static void* create(const char* config, char* error, size_t error_size) {
  (void)config, (void)error, (void)error_size;
  return &token;
}
static void destroy(void* instance) { (void)instance; }

static int handle_pdu(void* instance, uint8_t unit, const uint8_t* pdu, size_t len, uint8_t* out, size_t cap) {
  (void)instance, (void)unit;
  if (len >= 1 && pdu[0] == 0x41) {
    volatile int* nowhere = NULL;
    *nowhere = 1;
  }
  if (len == 5 && pdu[0] == 3 && cap >= 4) {
    out[0] = 3, out[1] = 2, out[2] = 0, out[3] = 0;
    return 4;
  }
  out[0] = (uint8_t)((len ? pdu[0] : 0) | 0x80);
  out[1] = 1;
  return 2;
}

static const mbconform_plugin_api_v1 api = {
    MBCONFORM_PLUGIN_ABI_VERSION, sizeof(mbconform_plugin_api_v1), "bench crash plugin", create, destroy, NULL,
    handle_pdu, NULL, NULL, NULL, NULL};

MBCONFORM_PLUGIN_EXPORT const mbconform_plugin_api_v1* mbconform_plugin_v1(void) { return &api; }
