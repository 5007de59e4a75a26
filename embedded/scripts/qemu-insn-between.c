/*
 * A QEMU TCG plugin (QEMU 7.2's plugin ABI, version 1) that counts the guest
 * instructions executed between two marker functions and prints one line
 * "insns N" per interval, in order, on QEMU's log (stderr):
 *
 *   qemu-system-arm ... -plugin ./qemu-insn-between.so,start=0x1234,stop=0x1240 -d plugin
 *
 * start/stop are the marker functions' entry addresses (the Thumb bit is
 * ignored). With total=on (markers optional) it prints "total N", every
 * instruction the guest executed, when QEMU exits (with profile=on, after
 * the "tb" lines of the whole run): board-instructions.sh takes the
 * difference of two runs of a whole firmware. With profile=on it also prints, before each "insns" line, one
 * "tb ADDR N" line per translation block that ran in the interval (N: the
 * instructions it executed there), for attributing the count to functions. Each translation block adds its instruction count to a counter
 * when it runs; a call ends a block, so a marker's entry always starts one.
 * The interval therefore includes the markers' own few instructions, which
 * cortex-m-instructions.sh measures with an empty interval and subtracts.
 *
 * Debian's QEMU is built with plugin support but ships neither plugins nor
 * qemu-plugin.h, so the handful of API declarations this needs are below.
 */
#include <inttypes.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef uint64_t qemu_plugin_id_t;
struct qemu_plugin_tb;
typedef struct qemu_info_t qemu_info_t;

enum qemu_plugin_cb_flags { QEMU_PLUGIN_CB_NO_REGS = 0 };
enum qemu_plugin_op { QEMU_PLUGIN_INLINE_ADD_U64 = 0 };

typedef void (*tb_trans_cb)(qemu_plugin_id_t id, struct qemu_plugin_tb *tb);
typedef void (*udata_cb)(qemu_plugin_id_t id, void *userdata);
typedef void (*vcpu_udata_cb)(unsigned int vcpu_index, void *userdata);

void qemu_plugin_register_vcpu_tb_trans_cb(qemu_plugin_id_t id, tb_trans_cb cb);
void qemu_plugin_register_vcpu_tb_exec_cb(struct qemu_plugin_tb *tb, vcpu_udata_cb cb,
                                          enum qemu_plugin_cb_flags flags, void *userdata);
void qemu_plugin_register_vcpu_tb_exec_inline(struct qemu_plugin_tb *tb, enum qemu_plugin_op op,
                                              void *ptr, uint64_t imm);
size_t qemu_plugin_tb_n_insns(const struct qemu_plugin_tb *tb);
uint64_t qemu_plugin_tb_vaddr(const struct qemu_plugin_tb *tb);
void qemu_plugin_outs(const char *string);
void qemu_plugin_register_atexit_cb(qemu_plugin_id_t id, udata_cb cb, void *userdata);

__attribute__((visibility("default"))) int qemu_plugin_version = 1;

/* One vCPU (the mps2 boards have one), so plain counters suffice. */
static uint64_t executed;
static uint64_t started;
static uint64_t start_addr, stop_addr;
static int profile;
static int total;
static int inside;

/* Per translated block, for profile=on: a list, since one address can be
 * translated more than once and blocks are never freed in a run this short. */
struct block {
    uint64_t vaddr;
    uint64_t insns;
    uint64_t executed;
    struct block *next;
};
static struct block *blocks;

static void on_block(unsigned int vcpu, void *udata)
{
    struct block *b = udata;
    (void)vcpu;
    if (inside || total) {
        b->executed += b->insns;
    }
}

static void on_start(unsigned int vcpu, void *udata)
{
    (void)vcpu;
    (void)udata;
    started = executed;
    inside = 1;
}

static void on_stop(unsigned int vcpu, void *udata)
{
    char line[64];
    (void)vcpu;
    (void)udata;
    inside = 0;
    for (struct block *b = blocks; b != NULL; b = b->next) {
        if (b->executed != 0) {
            snprintf(line, sizeof line, "tb 0x%" PRIx64 " %" PRIu64 "\n", b->vaddr, b->executed);
            qemu_plugin_outs(line);
            b->executed = 0;
        }
    }
    snprintf(line, sizeof line, "insns %" PRIu64 "\n", executed - started);
    qemu_plugin_outs(line);
}

static void on_qemu_exit(qemu_plugin_id_t id, void *udata)
{
    char line[64];
    (void)id;
    (void)udata;
    for (struct block *b = blocks; total && b != NULL; b = b->next) {
        if (b->executed != 0) {
            snprintf(line, sizeof line, "tb 0x%" PRIx64 " %" PRIu64 "\n", b->vaddr, b->executed);
            qemu_plugin_outs(line);
        }
    }
    snprintf(line, sizeof line, "total %" PRIu64 "\n", executed);
    qemu_plugin_outs(line);
}

static void on_translate(qemu_plugin_id_t id, struct qemu_plugin_tb *tb)
{
    uint64_t pc = qemu_plugin_tb_vaddr(tb);
    (void)id;
    /* Whichever order QEMU runs the add and a marker's callback in, it is
     * the same at both markers, so the interval is off by a constant. */
    qemu_plugin_register_vcpu_tb_exec_inline(tb, QEMU_PLUGIN_INLINE_ADD_U64, &executed,
                                             qemu_plugin_tb_n_insns(tb));
    if (profile) {
        struct block *b = calloc(1, sizeof *b);
        if (b == NULL) {
            abort();
        }
        b->vaddr = pc;
        b->insns = qemu_plugin_tb_n_insns(tb);
        b->next = blocks;
        blocks = b;
        qemu_plugin_register_vcpu_tb_exec_cb(tb, on_block, QEMU_PLUGIN_CB_NO_REGS, b);
    }
    if (pc == start_addr) {
        qemu_plugin_register_vcpu_tb_exec_cb(tb, on_start, QEMU_PLUGIN_CB_NO_REGS, NULL);
    } else if (pc == stop_addr) {
        qemu_plugin_register_vcpu_tb_exec_cb(tb, on_stop, QEMU_PLUGIN_CB_NO_REGS, NULL);
    }
}

__attribute__((visibility("default"))) int qemu_plugin_install(qemu_plugin_id_t id,
                                                               const qemu_info_t *info,
                                                               int argc, char **argv)
{
    (void)info;
    for (int i = 0; i < argc; i++) {
        if (strncmp(argv[i], "start=", 6) == 0) {
            start_addr = strtoull(argv[i] + 6, NULL, 0) & ~1ull;
        } else if (strncmp(argv[i], "stop=", 5) == 0) {
            stop_addr = strtoull(argv[i] + 5, NULL, 0) & ~1ull;
        } else if (strcmp(argv[i], "profile=on") == 0) {
            profile = 1;
        } else if (strcmp(argv[i], "total=on") == 0) {
            total = 1;
        } else {
            fprintf(stderr, "qemu-insn-between: unknown argument %s\n", argv[i]);
            return -1;
        }
    }
    if (!total && (start_addr == 0 || stop_addr == 0)) {
        fprintf(stderr, "qemu-insn-between: needs start=ADDR,stop=ADDR or total=on\n");
        return -1;
    }
    if (total) {
        qemu_plugin_register_atexit_cb(id, on_qemu_exit, NULL);
    }
    qemu_plugin_register_vcpu_tb_trans_cb(id, on_translate);
    return 0;
}
