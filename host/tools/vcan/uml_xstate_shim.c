/*
 * LD_PRELOAD shim for /usr/bin/linux.uml (Debian's 6.1 User-Mode Linux) on hosts whose CPU has
 * XSAVE components beyond UML's fixed FP buffer (e.g. Intel AMX: the xstate area is ~11 KiB).
 *
 * The problem: UML saves and restores its processes' FPU state with
 * ptrace(PTRACE_GETREGSET/PTRACE_SETREGSET, NT_X86_XSTATE) using its own, smaller buffer. The host
 * kernel's xstateregs_set() (arch/x86/kernel/fpu/regset.c) refuses any SETREGSET whose length is
 * not exactly the full user xstate size, with EFAULT, so UML dies at its first user process:
 * "userspace - ptrace set fp regs failed, errno = 14" and "Attempted to kill init!".
 *
 * The fix here: for such a SETREGSET, copy UML's buffer into a zeroed full-size one and clear the
 * xstate_bv bits of components that UML's buffer does not hold entirely (they are then restored
 * to their init state, which is what they are: UML's guest never enables AMX). GETREGSET with a
 * short buffer is already fine (the kernel truncates). Everything else passes through.
 * Component sizes and offsets come from CPUID leaf 0xD (Intel SDM vol. 1, 13.4 and 13.5).
 */
#define _GNU_SOURCE
#include <cpuid.h>
#include <dlfcn.h>
#include <elf.h>
#include <errno.h>
#include <stdarg.h>
#include <stdint.h>
#include <string.h>
#include <sys/ptrace.h>
#include <sys/syscall.h>
#include <sys/types.h>
#include <sys/uio.h>
#include <unistd.h>

#define XSTATE_MAX (64 * 1024)
#define XSTATE_BV_OFFSET 512

static size_t full_size; /* the host kernel's user xstate size, learnt once */
static size_t mask_len;
static uint64_t mask;
static __thread unsigned char buf[XSTATE_MAX] __attribute__((aligned(64)));

static size_t learn_full_size(pid_t pid) {
    struct iovec iov = {buf, sizeof buf};
    if (syscall(SYS_ptrace, PTRACE_GETREGSET, pid, (void *)NT_X86_XSTATE, &iov) != 0)
        return 0;
    return iov.iov_len;
}

static uint64_t components_within(size_t len) {
    uint64_t keep = 3; /* x87 and SSE live in the legacy area */
    for (unsigned i = 2; i < 63; i++) {
        unsigned eax, ebx, ecx, edx;
        __cpuid_count(0xD, i, eax, ebx, ecx, edx);
        if (eax != 0 && (size_t)ebx + eax <= len)
            keep |= (uint64_t)1 << i;
    }
    return keep;
}

long ptrace(enum __ptrace_request request, ...) {
    va_list ap;
    va_start(ap, request);
    pid_t pid = va_arg(ap, pid_t);
    void *addr = va_arg(ap, void *);
    void *data = va_arg(ap, void *);
    va_end(ap);

    if (request == PTRACE_SETREGSET && (uintptr_t)addr == NT_X86_XSTATE && data != NULL) {
        struct iovec *iov = data;
        if (full_size == 0)
            full_size = learn_full_size(pid);
        if (full_size > iov->iov_len && full_size <= XSTATE_MAX && iov->iov_len > XSTATE_BV_OFFSET + 8) {
            memset(buf, 0, full_size);
            memcpy(buf, iov->iov_base, iov->iov_len);
            uint64_t bv;
            memcpy(&bv, buf + XSTATE_BV_OFFSET, sizeof bv);
            if (mask_len != iov->iov_len) {
                mask = components_within(iov->iov_len);
                mask_len = iov->iov_len;
            }
            bv &= mask;
            memcpy(buf + XSTATE_BV_OFFSET, &bv, sizeof bv);
            struct iovec full = {buf, full_size};
            return syscall(SYS_ptrace, PTRACE_SETREGSET, pid, addr, &full);
        }
    }
    static long (*real)(enum __ptrace_request, ...);
    if (real == NULL)
        real = (long (*)(enum __ptrace_request, ...))dlsym(RTLD_NEXT, "ptrace");
    return real(request, pid, addr, data);
}
