/* The glove's CAN frames as the core sees them: one table entry per board of the DBC.
 *
 * The entries and the protocol codes (T4D_NMT_*, T4D_OUTPUT_*, T4D_FAULT_*) are generated from the
 * glove's DBC by tools/board_table.py into glove_boards.c/.h; the bit packing behind them is
 * cantools' generated glove.c. Nothing here is written by hand per glove.
 */
#ifndef T4D_PROTOCOL_H
#define T4D_PROTOCOL_H

#include <stddef.h>
#include <stdint.h>

#include "glove_boards.h"

#define T4D_MAX_CHANNELS 8u

/* The fields of a status frame, before packing. */
typedef struct {
    uint8_t state;        /* T4D_OUTPUT_* */
    uint8_t faults;       /* T4D_FAULT_* bits */
    uint8_t last_counter; /* Counter of the last duty frame applied */
    uint8_t active_mask;  /* bit K: channel K on */
    uint16_t bad_frames;  /* saturating */
} t4d_status_t;

/* One board of the glove: its frames and the functions that pack and unpack them. */
typedef struct {
    uint8_t node_id;
    uint8_t channels;
    uint32_t duty_id;
    uint8_t duty_length;
    uint8_t duty_full_scale; /* raw Duty_ChK value of 100 % duty */
    uint32_t status_id;
    uint8_t status_length;
    uint32_t status_cycle_ms;
    uint32_t heartbeat_id;
    uint8_t heartbeat_length;
    uint32_t heartbeat_cycle_ms;
    int (*unpack_duty)(const uint8_t *data, size_t size, uint8_t *counter, uint8_t *levels);
    int (*pack_status)(uint8_t *data, const t4d_status_t *status);
    int (*pack_heartbeat)(uint8_t *data, uint8_t state);
} t4d_board_proto_t;

extern const t4d_board_proto_t t4d_board_protos[T4D_BOARD_COUNT];

/* Command and target node of an NMT frame; 0 on success. */
int t4d_unpack_nmt(const uint8_t *data, size_t size, uint8_t *command, uint8_t *node);

/* The table entry of a node id, NULL if the glove has no such board. */
const t4d_board_proto_t *t4d_board_proto(uint8_t node_id);

#endif
