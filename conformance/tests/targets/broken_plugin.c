/* A deliberately broken plugin for the plugin host's tests: a PDU stack
 * that answers FC 03 with zeros and everything else with exception 01, and
 * breaks in one way (BROKEN_MODE) on a request with function code 0x41:
 *   1 segfault   2 abort   3 loop forever   4 a length over the capacity
 *   5 a negative length without an error message
 * and the modes the session's plugin tests use:
 *   6 segfault on every FC 06 (a run meets it in case after case)
 *   7 kill(getppid(), SIGKILL) on FC 0x41 (a plugin that signals its parent)
 *   8 forks a child on create that sleeps for ever, its pid written to the
 *     file named by the config (it must not outlive the run)
 *   9 allocates and touches 2 GiB on FC 0x41 (the memory limit stops it)
 *  10 loops forever on every FC 06
 *  11 like 8, but the child leaves the process group (setsid) and forks a
 *     grandchild that sleeps for ever (a daemon), its pid in the file
 *  12 segfault on every write (FC 05, 06, 15, 16, 22, 23) */
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "mbconform_plugin.h"

static int instance_token;

static void* create(const char* config, char* error, size_t error_size) {
  (void)config;
  (void)error;
  (void)error_size;
  if (BROKEN_MODE == 8 && config && *config) {
    pid_t child = fork();
    if (child == 0) {
      for (;;) pause();
    }
    FILE* f = fopen(config, "a");
    if (f) {
      fprintf(f, "%d\n", (int)child);
      fclose(f);
    }
  }
  if (BROKEN_MODE == 11 && config && *config) {
    if (fork() == 0) {
      setsid();
      pid_t grandchild = fork();
      if (grandchild == 0) {
        for (;;) pause();
      }
      FILE* f = fopen(config, "a");
      if (f) {
        fprintf(f, "%d\n", (int)grandchild);
        fclose(f);
      }
      _exit(0);
    }
  }
  return &instance_token;
}

static void destroy(void* instance) { (void)instance; }

static int handle_pdu(void* instance, uint8_t unit, const uint8_t* pdu, size_t len, uint8_t* out, size_t cap) {
  (void)instance;
  (void)unit;
  if (len >= 1 && pdu[0] == 0x06 && BROKEN_MODE == 6) {
    volatile int* nowhere = NULL;
    *nowhere = 1;
  }
  if (len >= 1 && BROKEN_MODE == 12 &&
      (pdu[0] == 0x05 || pdu[0] == 0x06 || pdu[0] == 0x0F || pdu[0] == 0x10 || pdu[0] == 0x16 || pdu[0] == 0x17)) {
    volatile int* nowhere = NULL;
    *nowhere = 1;
  }
  if (len >= 1 && pdu[0] == 0x06 && BROKEN_MODE == 10) {
    volatile int spin = 1;
    while (spin) {
    }
  }
  if (len >= 1 && pdu[0] == 0x41) {
    /* Through a variable: a mode with no case here (6, 8, 10-12 break
       elsewhere) is no constant switch condition clang warns about. */
    int mode = BROKEN_MODE;
    switch (mode) {
      case 7: kill(getppid(), SIGKILL); break;
      case 9: {
        size_t big = (size_t)2 << 30;
        char* p = malloc(big);
        if (!p) abort();
        memset(p, 1, big);
        free(p);
        break;
      }
      case 1: {
        volatile int* nowhere = NULL;
        *nowhere = 1;
        break;
      }
      case 2: abort();
      case 3: {
        volatile int spin = 1;
        while (spin) {
        }
        break;
      }
      case 4: memset(out, 0x41, cap); return (int)cap + 88;
      case 5: return -1;
    }
  }
  if (len == 5 && pdu[0] == 3) {
    size_t qty = (size_t)(pdu[3] << 8 | pdu[4]);
    if (qty >= 1 && qty <= 125 && 2 + 2 * qty <= cap) {
      out[0] = 3;
      out[1] = (uint8_t)(2 * qty);
      memset(out + 2, 0, 2 * qty);
      return (int)(2 + 2 * qty);
    }
  }
  out[0] = (uint8_t)((len ? pdu[0] : 0) | 0x80);
  out[1] = 1;
  return 2;
}

static const mbconform_plugin_api_v1 api = {
    MBCONFORM_PLUGIN_ABI_VERSION, sizeof(mbconform_plugin_api_v1), "broken test plugin", create, destroy, NULL,
    handle_pdu, NULL, NULL, NULL, NULL};

MBCONFORM_PLUGIN_EXPORT const mbconform_plugin_api_v1* mbconform_plugin_v1(void) { return &api; }
