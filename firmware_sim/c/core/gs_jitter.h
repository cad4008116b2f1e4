/* Jitter buffer: timed servo frames ordered by (apply-at, arrival), fixed capacity
 * (firmware_sim/jitter_buffer.py): a later frame with the same apply-at overrides an earlier one
 * for the servos both cover; per servo the earliest buffered (apply-at, target) is cached. */
#ifndef GS_JITTER_H
#define GS_JITTER_H

#include <stdint.h>

#include "gs_config.h"

#if GS_SERVO_COUNT <= 16
typedef uint16_t gs_mask_t; /* bit i = servo i (id i + 1) */
#else
typedef uint32_t gs_mask_t;
#endif

/* Frames are kept sorted by apply-at, equal times in arrival order (a new frame goes after them). */
typedef struct {
    int64_t apply_at_us;
    uint16_t seq;
    gs_mask_t mask;
    int16_t q[GS_SERVO_COUNT]; /* target of servo i (q16 code, 1e-4 rad) where mask bit i is set */
} gs_jframe_t;

typedef struct {
    gs_jframe_t f[GS_BUFFER_DEPTH];
    uint16_t n;
    uint8_t next_valid;
    uint8_t has_next[GS_SERVO_COUNT];
    int64_t next_t[GS_SERVO_COUNT];
    int16_t next_q[GS_SERVO_COUNT];
} gs_jb_t;

void gs_jb_init(gs_jb_t *b);
/* Insert a frame; 0 (nothing stored) when full. */
int gs_jb_push(gs_jb_t *b, int64_t apply_at_us, uint16_t seq, gs_mask_t mask, const int16_t *q_by_servo);
/* Number of frames at the front due at `t_us` (apply-at <= t); read b->f[0..k), then drop them. */
uint16_t gs_jb_due(const gs_jb_t *b, int64_t t_us);
void gs_jb_drop_front(gs_jb_t *b, uint16_t k);
/* Drop targets due at or after `from_us` for the masked servos; returns the servos touched. */
gs_mask_t gs_jb_flush(gs_jb_t *b, int64_t from_us, gs_mask_t mask);
/* Refresh the per-servo next keyframe cache (has_next, next_t, next_q). */
void gs_jb_next_all(gs_jb_t *b);
int gs_jb_pending_for(gs_jb_t *b, unsigned servo);
void gs_jb_clear(gs_jb_t *b);
/* Apply-at of the last frame (returns 0 when empty). */
int gs_jb_latest(const gs_jb_t *b, int64_t *t);

#endif
