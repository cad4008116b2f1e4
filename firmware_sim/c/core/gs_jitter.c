#include "gs_jitter.h"

void gs_jb_init(gs_jb_t *b) {
    b->n = 0;
    b->next_valid = 0;
}

void gs_jb_clear(gs_jb_t *b) {
    b->n = 0;
    b->next_valid = 0;
}

int gs_jb_push(gs_jb_t *b, int64_t apply_at_us, uint16_t seq, gs_mask_t mask, const int16_t *q) {
    if (b->n >= GS_BUFFER_DEPTH) return 0;
    uint16_t pos = b->n;
    while (pos > 0 && b->f[pos - 1].apply_at_us > apply_at_us) pos--; /* after equal times: arrival order */
    for (uint16_t k = b->n; k > pos; k--) b->f[k] = b->f[k - 1];
    gs_jframe_t *f = &b->f[pos];
    f->apply_at_us = apply_at_us;
    f->seq = seq;
    f->mask = mask;
    for (unsigned i = 0; i < GS_SERVO_COUNT; i++) f->q[i] = (mask >> i & 1u) ? q[i] : 0;
    b->n++;
    b->next_valid = 0;
    return 1;
}

uint16_t gs_jb_due(const gs_jb_t *b, int64_t t_us) {
    uint16_t k = 0;
    while (k < b->n && b->f[k].apply_at_us <= t_us) k++;
    return k;
}

void gs_jb_drop_front(gs_jb_t *b, uint16_t k) {
    if (!k) return;
    for (uint16_t i = k; i < b->n; i++) b->f[i - k] = b->f[i];
    b->n = (uint16_t)(b->n - k);
    b->next_valid = 0;
}

gs_mask_t gs_jb_flush(gs_jb_t *b, int64_t from_us, gs_mask_t mask) {
    gs_mask_t touched = 0;
    uint16_t kept = 0;
    for (uint16_t i = 0; i < b->n; i++) {
        gs_jframe_t *f = &b->f[i];
        if (f->apply_at_us >= from_us) {
            touched |= f->mask & mask;
            f->mask &= ~mask;
            if (!f->mask) continue;
        }
        if (kept != i) b->f[kept] = *f;
        kept++;
    }
    b->n = kept;
    b->next_valid = 0;
    return touched;
}

void gs_jb_next_all(gs_jb_t *b) {
    if (b->next_valid) return;
    unsigned missing = GS_SERVO_COUNT;
    for (unsigned i = 0; i < GS_SERVO_COUNT; i++) b->has_next[i] = 0;
    for (uint16_t k = 0; k < b->n && missing; k++) {
        const gs_jframe_t *f = &b->f[k];
        for (unsigned i = 0; i < GS_SERVO_COUNT; i++) {
            if ((f->mask >> i & 1u) && !b->has_next[i]) {
                b->has_next[i] = 1;
                b->next_t[i] = f->apply_at_us;
                b->next_q[i] = f->q[i];
                missing--;
            }
        }
    }
    b->next_valid = 1;
}

int gs_jb_pending_for(gs_jb_t *b, unsigned servo) {
    gs_jb_next_all(b);
    return b->has_next[servo];
}

int gs_jb_latest(const gs_jb_t *b, int64_t *t) {
    if (!b->n) return 0;
    *t = b->f[b->n - 1].apply_at_us;
    return 1;
}
