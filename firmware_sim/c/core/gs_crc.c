/* CRC-16/X-25 bit by bit (reflected poly 0x8408): 32 bytes of code instead of a 512-byte table;
 * at most 262 bytes per frame, so the cost is small next to the control tick. */
#include "gs_crc.h"

uint16_t gs_crc16_x25(const uint8_t *data, size_t n) {
    uint16_t crc = 0xFFFFu;
    for (size_t i = 0; i < n; i++) {
        crc ^= data[i];
        for (int b = 0; b < 8; b++) crc = (uint16_t)((crc & 1u) ? (crc >> 1) ^ 0x8408u : crc >> 1);
    }
    return (uint16_t)(crc ^ 0xFFFFu);
}
