/* CRC-16/X-25 (CRC-16/IBM-SDLC): poly 0x1021 reflected, init 0xFFFF, xorout 0xFFFF; check 0x906E.
 * The serial framing's CRC (protocol/framing.py uses crcmod's predefined 'x-25'). */
#ifndef GS_CRC_H
#define GS_CRC_H
#include <stddef.h>
#include <stdint.h>
uint16_t gs_crc16_x25(const uint8_t *data, size_t n);
#endif
