/* vibid_drivers/register_map.h: Modbus register maps as Telegraf and collectd users
 * write them, in libconfig syntax, and decoding of register arrays.
 *
 *   registers = (
 *     { name = "x1"; address = 100; register = "holding"; type = "FLOAT32";
 *       byte_order = "ABCD"; scale = 1.0; },            # scale optional (1.0)
 *     { name = "F";  address = 0;   register = "input";  type = "INT16"; scale = 0.01; }
 *   );
 *
 * address: 0-based register address (protocol address, not the 4xxxx notation), 0..65535,
 * and address + words - 1 must also be <= 65535. register: "holding" or "input".
 * type: INT16, UINT16 (1 register), INT32, UINT32, FLOAT32 (2), FLOAT64 (4).
 * byte_order (default ABCD): the value's bytes from most significant, A B C D (E..H
 * for 64-bit), as they appear in consecutive registers, each register big endian:
 *   ABCD  big endian (AB CD [EF GH])          CDAB  word-swapped (CD AB; 64-bit GH EF CD AB)
 *   BADC  byte-swapped in each word (BA DC)   DCBA  little endian (DC BA; 64-bit HG FE DC BA)
 * For 16-bit types ABCD/CDAB read AB and BADC/DCBA read BA.
 * value = raw * scale + offset (offset optional, default 0). Names are unique. Any other
 * key is an error (vibid/cfgread.h: a misspelt byte_order must not read as ABCD).
 */
#ifndef VIBID_DRIVERS_REGISTER_MAP_H
#define VIBID_DRIVERS_REGISTER_MAP_H

#include <stddef.h>
#include <stdint.h>

#include <libconfig.h>
#include <vibid/cfgread.h>
#include <vibid_drivers/status.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef enum vibid_reg_kind { VIBID_REG_HOLDING = 0, VIBID_REG_INPUT = 1 } vibid_reg_kind;
typedef enum vibid_reg_type {
    VIBID_REG_INT16, VIBID_REG_UINT16, VIBID_REG_INT32, VIBID_REG_UINT32,
    VIBID_REG_FLOAT32, VIBID_REG_FLOAT64
} vibid_reg_type;
typedef enum vibid_reg_order {
    VIBID_REG_ABCD, VIBID_REG_DCBA, VIBID_REG_BADC, VIBID_REG_CDAB
} vibid_reg_order;

#define VIBID_REG_NAME_LEN 64

typedef struct vibid_reg_entry {
    char name[VIBID_REG_NAME_LEN];
    uint16_t address;      /* first register, 0-based */
    vibid_reg_kind kind;
    vibid_reg_type type;
    vibid_reg_order order;
    double scale, offset;  /* finite */
    unsigned line;         /* line of the entry in its file (0 if unknown) */
} vibid_reg_entry;

typedef struct vibid_regmap {
    size_t n;
    vibid_reg_entry *entries; /* owned by the map */
} vibid_regmap;

/* Reads the register list `list` (e.g. vibidd's source.registers) with the configuration
 * reader r (vibid/cfgread.h); path is the list's setting path ("registers",
 * "source.registers") for the fields in messages. NULL on failure (reason in r->err). */
vibid_regmap *vibid_regmap_read(const vibid_cfg_reader *r, const config_setting_t *list, const char *path);
/* Reads a register-map file: a root holding only the list `registers`. */
vibid_regmap *vibid_regmap_read_file(const char *path, vibid_cfg_error *err);
/* The same with the drivers' error holder (err->text = the reader's text). */
vibid_regmap *vibid_regmap_load(const char *path, vibid_drv_error *err);
void vibid_regmap_destroy(vibid_regmap *map);
const vibid_reg_entry *vibid_regmap_find(const vibid_regmap *map, const char *name);

/* Registers a type occupies: 1, 2 or 4. */
unsigned vibid_reg_type_words(vibid_reg_type type);
/* Decodes entry e from regs[], which holds registers first_address ..
 * first_address + n_regs - 1 of e's kind. VIBID_DRV_E_RANGE if e lies outside that
 * block. Float registers may decode to NaN/Inf: the value is returned as is (status
 * OK) and the caller decides; see vibid_reg_decode_checked. No allocation. */
vibid_drv_status vibid_reg_decode(const vibid_reg_entry *e, const uint16_t *regs, size_t n_regs,
                                  uint16_t first_address, double *value);
/* Encodes a physical value into registers (inverse of decode; integers rounded to
 * nearest and range-checked: VIBID_DRV_E_RANGE if it does not fit). For servers and tests. */
vibid_drv_status vibid_reg_encode(const vibid_reg_entry *e, double value, uint16_t *words);

#ifdef __cplusplus
}
#endif
#endif
