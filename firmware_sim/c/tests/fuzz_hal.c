/* HAL for the fuzz targets: the host UART reads from a buffer the target fills, writes go nowhere,
 * the clock is virtual (every reading advances it 50 us, so bus timeouts end at once), and a tiny
 * bus responder answers PING, READ and SYNC READ for the servos, the IMU and the probe (zeros for
 * data, the last goal for present positions) so the board runs its normal path. */
#include <string.h>

#include "fuzz_hal.h"
#include "gs_bus.h"
#include "gs_hal.h"
#include "gs_servo_table.h"

const uint8_t *fuzz_in;
size_t fuzz_in_len, fuzz_in_pos;
static uint64_t vclock;
static uint8_t bus_out[512];
static size_t bus_out_len, bus_out_pos;
static uint16_t goal[256];

void fuzz_hal_reset(void) {
    vclock = 0;
    bus_out_len = bus_out_pos = 0;
    for (unsigned i = 0; i < 256; i++) goal[i] = 2048;
}

uint64_t hal_now_us(void) { return vclock += 50; }

size_t hal_host_read(uint8_t *buf, size_t cap) {
    size_t n = fuzz_in_len - fuzz_in_pos;
    if (n > cap) n = cap;
    memcpy(buf, fuzz_in + fuzz_in_pos, n);
    fuzz_in_pos += n;
    return n;
}

size_t hal_host_write(const uint8_t *buf, size_t n) {
    (void)buf;
    return n;
}

static void status(uint8_t id, const uint8_t *params, size_t n) {
    if (bus_out_len + n + 6 > sizeof bus_out) return;
    uint8_t *p = &bus_out[bus_out_len];
    unsigned sum = id + (unsigned)(n + 2);
    p[0] = p[1] = 0xFF;
    p[2] = id;
    p[3] = (uint8_t)(n + 2);
    p[4] = 0;
    for (size_t i = 0; i < n; i++) {
        p[5 + i] = params[i];
        sum += params[i];
    }
    p[5 + n] = (uint8_t)~sum;
    bus_out_len += n + 6;
}

static void data_for(uint8_t id, uint8_t addr, uint8_t len, uint8_t *d) {
    memset(d, 0, len);
    if (id >= 1 && id <= GS_SERVO_COUNT && addr == GS_REG_PRESENT && len >= 2) {
        d[0] = (uint8_t)goal[id];
        d[1] = (uint8_t)(goal[id] >> 8);
    }
}

void hal_bus_write(const uint8_t *buf, size_t n) {
    if (n < 6 || buf[0] != 0xFF || buf[1] != 0xFF) return;
    uint8_t id = buf[2], len = buf[3], inst = buf[4];
    const uint8_t *p = &buf[5];
    size_t np = (size_t)len - 2u;
    uint8_t d[64];
    if (inst == GS_INST_PING) status(id, 0, 0);
    else if (inst == GS_INST_READ && np == 2 && p[1] <= sizeof d) {
        data_for(id, p[0], p[1], d);
        status(id, d, p[1]);
    } else if (inst == GS_INST_SYNC_READ && np >= 2 && p[1] <= sizeof d) {
        for (size_t k = 2; k < np; k++) {
            data_for(p[k], p[0], p[1], d);
            status(p[k], d, p[1]);
        }
    } else if (inst == GS_INST_SYNC_WRITE && np >= 2 && p[0] == GS_REG_GOAL_POSITION && p[1] == 2) {
        for (size_t k = 2; k + 2 < np; k += 3) goal[p[k]] = (uint16_t)(p[k + 1] | p[k + 2] << 8);
    }
}

size_t hal_bus_read(uint8_t *buf, size_t cap, uint32_t timeout_us) {
    (void)timeout_us;
    size_t n = bus_out_len - bus_out_pos;
    if (n > cap) n = cap;
    memcpy(buf, bus_out + bus_out_pos, n);
    bus_out_pos += n;
    if (bus_out_pos == bus_out_len) bus_out_pos = bus_out_len = 0;
    return n;
}

void hal_bus_drain(void) { bus_out_pos = bus_out_len = 0; }

void hal_wait(uint64_t until_us, int want_write) {
    (void)want_write;
    if (until_us > vclock) vclock = until_us;
}

void hal_log_write(const char *s, size_t n) {
    (void)s;
    (void)n;
}

int hal_should_stop(void) { return 0; }

uint32_t hal_cycles(void) { return 0; }
