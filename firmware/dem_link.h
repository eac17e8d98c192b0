/*
 * dem_link: the dem_ros board <-> PC device link, frame codec for board firmware.
 *
 * Portable C99. No malloc, no libc beyond <string.h> (memcpy) and <stdint.h>/<stddef.h>.
 * Protocol: docs/hardware-link.md; definition: tests/hardware/vectors/frames.txt
 * (this codec passes it: see firmware/README.md).
 *
 * Frames are little-endian with a fixed layout:
 *   [0] version u8  [1] type u8  [2..3] length u16 (whole frame, CRC included)
 *   payload (fixed per type)    last 4 bytes: CRC-32 (IEEE, as zlib.crc32) of all before it
 * Sizes: hello 24, sensor 48, command 24, config 128, config ack 20 bytes.
 * Serial lines carry 0x00, COBS(frame), 0x00 for each frame; UDP one frame per datagram.
 *
 * Floats are IEEE-754 binary32 (the platform's float must be binary32, as on every
 * Cortex-M, AVR with avr-gcc's 32-bit float, RISC-V and x86).
 */
#ifndef DEM_LINK_H
#define DEM_LINK_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define DEM_LINK_VERSION 1u
#define DEM_HELLO_SIZE 24u
#define DEM_SENSOR_SIZE 48u
#define DEM_COMMAND_SIZE 24u
#define DEM_CONFIG_SIZE 128u
#define DEM_CONFIG_ACK_SIZE 20u
#define DEM_MAX_FRAME_SIZE 128u
/* COBS adds ceil(n/254) bytes: a 128-byte frame is at most 129 bytes, plus the 0x00 delimiter. */
#define DEM_MAX_ENCODED_SIZE 129u

enum dem_frame_type { DEM_HELLO = 1, DEM_SENSOR = 2, DEM_COMMAND = 3, DEM_CONFIG = 4, DEM_CONFIG_ACK = 5 };

/* The board's safety-supervisor mode (the mode byte). Commands may request OFF, RUN, HOLD, LAND. */
enum dem_mode { DEM_OFF = 0, DEM_RUN = 1, DEM_HOLD = 2, DEM_LAND = 3, DEM_LANDED = 4, DEM_FAULT = 5 };

/* Status bits of a sensor frame (bits 18-31 reserved: send 0, ignore on receipt). */
#define DEM_ST_GAP0_RANGE (1ul << 0)       /* gap sensor 1 out of range (ADC railed / sensor missing) */
#define DEM_ST_GAP1_RANGE (1ul << 1)       /* gap sensor 2 out of range */
#define DEM_ST_CURRENT0_LIMIT (1ul << 2)   /* coil 1 current above the hardware limit (tripped) */
#define DEM_ST_CURRENT1_LIMIT (1ul << 3)   /* coil 2 current above the hardware limit (tripped) */
#define DEM_ST_DRIVER0_FAULT (1ul << 4)    /* coil driver 1 fault pin / over-temperature */
#define DEM_ST_DRIVER1_FAULT (1ul << 5)    /* coil driver 2 fault */
#define DEM_ST_BUS_UNDERVOLTAGE (1ul << 6) /* DC bus below the driver's minimum */
#define DEM_ST_BUS_OVERVOLTAGE (1ul << 7)  /* DC bus above the driver's maximum */
#define DEM_ST_LINK_TIMEOUT (1ul << 8)     /* no valid command within the link watchdog: landing */
#define DEM_ST_COMMAND_LATE (1ul << 9)     /* no fresh command for the previous sample: held */
#define DEM_ST_RX_ERROR (1ul << 10)        /* a received frame was rejected since the last sensor frame */
#define DEM_ST_VOLTAGE_CLIPPED (1ul << 11) /* the commanded voltage was clipped to the driver's limit */
#define DEM_ST_ESTOP (1ul << 12)           /* hardware emergency-stop input active */
#define DEM_ST_OVERRUN (1ul << 13)         /* the board missed its own sample deadline */
#define DEM_ST_GAP_LIMIT (1ul << 14)       /* a gap outside the safe band (tripped) */
#define DEM_ST_ADC_FAULT (1ul << 15)       /* ADC conversion failed or timed out */
#define DEM_ST_GAP0_IMPLAUSIBLE (1ul << 16) /* gap sensor 1 contradicts coil 1's flux: ignored, landing (latched) */
#define DEM_ST_GAP1_IMPLAUSIBLE (1ul << 17) /* gap sensor 2 contradicts coil 2's flux (latched) */

/* Results; the names (dem_link_reason) are the Python LinkError reasons. */
enum dem_link_result {
    DEM_OK = 0,
    DEM_ERR_SHORT,     /* fewer than 8 bytes */
    DEM_ERR_LENGTH,    /* header length != bytes received */
    DEM_ERR_CRC,       /* CRC-32 mismatch */
    DEM_ERR_VERSION,   /* sensor/command frame of another version, or a hello of version 0 */
    DEM_ERR_TYPE,      /* unknown type */
    DEM_ERR_SIZE,      /* length does not match the type */
    DEM_ERR_RESERVED,  /* a reserved byte is not zero */
    DEM_ERR_MODE,      /* mode outside enum dem_mode, or a command requesting LANDED/FAULT */
    DEM_ERR_NONFINITE, /* a float is NaN or infinite */
    DEM_ERR_RANGE,     /* a field outside its range (adc_bits > 16, adc_vref < 0, version 0, an ack's result/flag) */
    DEM_ERR_BUFFER     /* (encode/COBS only) the output buffer is too small; never from dem_decode */
};

typedef struct {
    uint8_t version;      /* protocol version the sender speaks */
    uint32_t board_id;    /* 0 in the PC's request */
    uint32_t rate_hz;     /* sample rate [Hz]; 0 in the request */
    uint8_t adc_bits;     /* ADC resolution [bit], 0..16; 0 in the request */
    uint8_t command_delay;/* d [samples]: at tick k the board applies the command answering k-d; 0 in the request */
    uint16_t watchdog_ms; /* the board's link watchdog [ms]; 0 in the request */
    float adc_vref;       /* ADC full scale [V], >= 0 */
} dem_hello_t;

typedef struct {
    uint32_t seq;              /* sample number, +1 per sample, wraps */
    uint64_t board_time_us;    /* board clock at the sample [us] */
    uint16_t gap_counts[2];    /* raw ADC counts, gap sensors 1, 2 */
    uint16_t current_counts[2];/* raw ADC counts, coil current sensors 1, 2 */
    float applied_v[2];        /* voltage actually applied over the period ending here [V] */
    float bus_v;               /* measured DC bus [V] */
    uint32_t status;           /* DEM_ST_* bits */
    uint8_t mode;              /* enum dem_mode */
} dem_sensor_t;

typedef struct {
    uint32_t seq;  /* the sensor seq this command answers */
    float u[2];    /* coil voltages [V] (the board clips them) */
    uint8_t mode;  /* DEM_OFF, DEM_RUN, DEM_HOLD or DEM_LAND */
} dem_command_t;

/* The configuration frame's floats: the supervisor's (sup_config_t, in its order: u_max, i_max, trip_gap_min,
 * trip_gap_max, hold_timeout, landing_gap, landing_speed, m, R, K, L, l, I, N1, N2, g, dt), then the sensors'
 * calibration (gap1_c0..c3, gap2_c0..c3, current1_gain, current2_gain, current1_offset, current2_offset). */
#define DEM_CONFIG_SUP 17u
#define DEM_CONFIG_CAL 12u
#define DEM_CONFIG_FLOATS (DEM_CONFIG_SUP + DEM_CONFIG_CAL)

typedef struct {
    float v[DEM_CONFIG_FLOATS]; /* finite (the codec refuses NaN/inf); the board checks the rest */
    uint8_t command_delay;      /* d [samples] */
} dem_config_t;

/* A config ack's result: 0 accepted, else why the board refused (1-5 are supervisor.h's sup_cfg_result). */
enum dem_config_result {
    DEM_CFG_OK = 0,
    DEM_CFG_NOT_POSITIVE, /* a value that must be positive is not */
    DEM_CFG_GAP_ORDER,    /* not 0 <= trip_gap_min < landing_gap <= trip_gap_max */
    DEM_CFG_ARMS,         /* not l < L */
    DEM_CFG_NO_BRAKING,   /* the loads leave no pull away from the rail at an end */
    DEM_CFG_NONFINITE,    /* a value is not finite */
    DEM_CFG_DELAY,        /* command_delay outside the board's range */
    DEM_CFG_RATE,         /* dt is not the board's sample period */
    DEM_CFG_BUSY          /* the board is not OFF or LANDED: never a change in flight */
};

typedef struct {
    uint32_t active_crc;  /* CRC-32 of the configuration the board runs after this request */
    uint32_t request_crc; /* CRC-32 of the configuration this answers */
    uint8_t result;       /* enum dem_config_result */
    uint8_t configured;   /* 1: set over the link; 0: the board's compiled-in defaults */
    uint8_t mode;         /* enum dem_mode when the board answered */
} dem_config_ack_t;

typedef struct {
    uint8_t type; /* enum dem_frame_type */
    union {
        dem_hello_t hello;
        dem_sensor_t sensor;
        dem_command_t command;
        dem_config_t config;
        dem_config_ack_t config_ack;
    } f;
} dem_frame_t;

/* CRC-32 (reflected 0xEDB88320, init and final xor 0xFFFFFFFF), as zlib.crc32. */
uint32_t dem_crc32(const uint8_t *data, size_t n);

/* Serialise; *len receives the frame size. Returns DEM_OK, DEM_ERR_* for a bad field, DEM_ERR_BUFFER. */
int dem_encode(const dem_frame_t *frame, uint8_t *out, size_t cap, size_t *len);

/* Parse exactly one frame of n bytes. Returns DEM_OK (frame filled) or the reason it was rejected. */
int dem_decode(const uint8_t *data, size_t n, dem_frame_t *frame);

/* "ok", "short", "length", "crc", ... ("buffer" for DEM_ERR_BUFFER; "?" for anything else). */
const char *dem_link_reason(int result);

/* The CRC-32 of a configuration: the CRC field of its config frame (its canonical bytes). Not validated. */
uint32_t dem_config_crc(const dem_config_t *config);
/* "ok", "not_positive", ... "busy" (the Python codec's CONFIG_RESULTS); "?" for anything else. */
const char *dem_config_reason(int result);

/* COBS. Encode: *len = encoded size (no delimiter); decode: *len = decoded size. */
int dem_cobs_encode(const uint8_t *in, size_t n, uint8_t *out, size_t cap, size_t *len);
int dem_cobs_decode(const uint8_t *in, size_t n, uint8_t *out, size_t cap, size_t *len);

/* Byte-at-a-time deframer for a UART receive path (interrupt or DMA ring). Bounded memory;
 * resynchronises at the next 0x00 after garbage; drops counted. */
typedef struct {
    uint8_t buf[DEM_MAX_ENCODED_SIZE];
    size_t len;
    int skipping;              /* inside an over-long run: discard up to the next 0x00 */
    uint32_t frames;           /* COBS-valid segments delivered */
    uint32_t dropped_cobs;     /* segments that were not valid COBS */
    uint32_t dropped_oversize; /* runs longer than DEM_MAX_ENCODED_SIZE without a delimiter */
} dem_deframer_t;

void dem_deframer_init(dem_deframer_t *d);
/* Push one received byte. Returns 1 when it completes a frame (its COBS-decoded bytes are in
 * out[0..*len), cap >= DEM_MAX_FRAME_SIZE), else 0. Pass the frame on to dem_decode. */
int dem_deframer_push(dem_deframer_t *d, uint8_t byte, uint8_t *out, size_t cap, size_t *len);

#ifdef __cplusplus
}
#endif
#endif /* DEM_LINK_H */
