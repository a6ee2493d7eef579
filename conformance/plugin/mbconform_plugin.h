/*
 * mbconform plugin ABI, version 1: a vendor's Modbus slave stack, compiled
 * for the host as a shared library, tested by `mbconform run --target
 * plugin:./libmystack.so --device ID` with the same cases as a live drive.
 *
 * Pure C, self-contained (only <stddef.h> and <stdint.h>), stable: a later
 * version only appends fields to the struct and raises
 * MBCONFORM_PLUGIN_ABI_VERSION; the host reads `struct_size` to know which
 * fields a plugin has.
 *
 * The plugin exports one symbol, `mbconform_plugin_v1`, a function returning
 * a pointer to a static table of function pointers:
 *
 *     static const mbconform_plugin_api_v1 api = {
 *         MBCONFORM_PLUGIN_ABI_VERSION, sizeof(mbconform_plugin_api_v1),
 *         "mystack 2.3", my_create, my_destroy, my_handle_rtu, NULL,
 *         my_reset, my_power_cycle, NULL, my_last_error};
 *     MBCONFORM_PLUGIN_EXPORT const mbconform_plugin_api_v1* mbconform_plugin_v1(void) { return &api; }
 *
 * Frames are Modbus RTU ADUs (MB over Serial Line v1.02 §2.5.1): slave
 * address, PDU, CRC-16 low byte first. The host gives the stack every frame
 * a master would put on the line, including malformed ones (bad CRC,
 * truncated, over-long, other slave ids, broadcast); the stack answers as it
 * would on RS-485: a reply ADU, or nothing (silence).
 *
 * Rules for a plugin:
 *  - Any input must be safe: any length from 0 up (over-long frames exceed
 *    MBCONFORM_MAX_RTU_ADU), any bytes. The host also drives plugins from a
 *    fuzzer (libFuzzer, in process): never crash, never read past `request_len`,
 *    never write past `response_capacity`, never block, never exit().
 *  - Instances are independent: the host may create several; it calls one
 *    instance from one thread at a time.
 *  - No global state that outlives destroy() (a fuzzer creates and destroys
 *    instances many times).
 */
#ifndef MBCONFORM_PLUGIN_H
#define MBCONFORM_PLUGIN_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define MBCONFORM_PLUGIN_ABI_VERSION 1u
/* The exported symbol's name, for dlsym(). */
#define MBCONFORM_PLUGIN_ENTRY "mbconform_plugin_v1"
/* The largest well-formed RTU ADU: address, 253-byte PDU, CRC (MB-SL §2.5.1.1). */
#define MBCONFORM_MAX_RTU_ADU 256u
/* The largest PDU (MBAP v1.1b3 §4.1). */
#define MBCONFORM_MAX_PDU 253u
/* The host's response buffer is at least this large. */
#define MBCONFORM_RESPONSE_CAPACITY 512u

#if defined(_WIN32)
#define MBCONFORM_PLUGIN_EXPORT __declspec(dllexport)
#else
#define MBCONFORM_PLUGIN_EXPORT __attribute__((visibility("default")))
#endif

typedef struct mbconform_plugin_api_v1 {
  /* MBCONFORM_PLUGIN_ABI_VERSION the plugin was built against. */
  uint32_t abi_version;
  /* sizeof(mbconform_plugin_api_v1) as the plugin was built. */
  uint32_t struct_size;
  /* The stack's name and version, for reports ("libmodbus 3.1.6 modbus_reply"). */
  const char* name;

  /* Required. Makes an instance from `config` (the target URI's config=
   * parameter, "" when absent; the format is the plugin's own). Returns NULL
   * on failure after writing a message (NUL-terminated, at most error_size
   * bytes) into `error`. */
  void* (*create)(const char* config, char* error, size_t error_size);
  /* Required. Frees the instance. */
  void (*destroy)(void* instance);

  /* At least one of handle_rtu and handle_pdu is required.
   *
   * handle_rtu: one RTU ADU as it came off the line (possibly malformed).
   * Writes the reply ADU to `response` and returns its length; 0 = no reply
   * (silence); negative = the plugin itself failed (see last_error). With it
   * the host can send malformed frames (target info: raw). */
  int (*handle_rtu)(void* instance, const uint8_t* request, size_t request_len, uint8_t* response,
                    size_t response_capacity);
  /* handle_pdu: for a stack without its own framing: one well-formed PDU
   * addressed to `unit` (0 = broadcast). Writes the reply PDU and returns its
   * length; 0 = no reply; negative = failure. Used only when handle_rtu is
   * NULL (then no malformed-frame cases run). */
  int (*handle_pdu)(void* instance, uint8_t unit, const uint8_t* pdu, size_t pdu_len, uint8_t* response,
                    size_t response_capacity);

  /* Optional (NULL when absent). Back to the state right after create()
   * (a fuzzer calls it between inputs). 0 on success. */
  int (*reset)(void* instance);
  /* Optional. Power off and on: volatile state is lost, what the device
   * keeps in EEPROM/flash survives (target info: power_cycle). 0 on success. */
  int (*power_cycle)(void* instance);
  /* Optional. Moves the stack's clock forward by `us` microseconds (timeouts,
   * motion, delayed effects), for a deterministic run (target info:
   * virtual_clock). */
  void (*advance_time_us)(void* instance, uint64_t us);
  /* Optional. The last failure of `instance` as text (valid until the next call). */
  const char* (*last_error)(void* instance);
} mbconform_plugin_api_v1;

/* The one exported entry point. */
typedef const mbconform_plugin_api_v1* (*mbconform_plugin_entry_fn)(void);
MBCONFORM_PLUGIN_EXPORT const mbconform_plugin_api_v1* mbconform_plugin_v1(void);

#ifdef __cplusplus
}
#endif

#endif /* MBCONFORM_PLUGIN_H */
