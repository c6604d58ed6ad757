/* Last words of a process that dies from a fatal signal: write a prepared summary.json.
 *
 * A crash in native code inside the run's process (an FMU dereferencing NULL, calling abort(),
 * a bug in a compiled helper) ends the process before Python can write anything. This handler,
 * installed for SIGSEGV, SIGBUS, SIGFPE, SIGILL and SIGABRT, writes a summary that Python prepared
 * beforehand (status "failed", the run's last known progress) with the signal's name in place of
 * every \x01 byte and the latest progress in place of every \x02 (simulated seconds in all) and
 * \x03 (the running part's own time) byte, using only async-signal-safe calls (open, write, close,
 * rename), then hands the signal to the previous handler (or the default action) so the process
 * still dies from it. The progress is two doubles the run writes at every heartbeat
 * (crashguard_progress), so the summary says where the run was to the heartbeat. */
#define _XOPEN_SOURCE 700 /* sigaction, sigaltstack, SA_ONSTACK under -std=c99 */
#include <fcntl.h>
#include <stdio.h> /* rename */
#include <signal.h>
#include <stddef.h>
#include <string.h>
#include <unistd.h>

#define CAPACITY (1 << 17)
static char target[4096], temporary[4100];
static char text[CAPACITY];
static size_t text_len;
static volatile sig_atomic_t armed;
static const int watched[] = {SIGSEGV, SIGBUS, SIGFPE, SIGILL, SIGABRT};
#define N_WATCHED (sizeof watched / sizeof watched[0])
static struct sigaction previous[N_WATCHED];
static int installed;
static char alt_stack[1 << 16];
static volatile double progress[2] = {-1.0, -1.0}; /* sim_time_s, stopped_at_s; < 0: none yet */

/* The two progress doubles (simulated seconds in all, the running part's time), written by the run. */
volatile double *crashguard_progress(void) { return progress; }

/* ``value`` as JSON text into ``out`` (at least 40 bytes): "null" when < 0 or not finite, else
 * the number rounded to 1e-9 with its trailing zeros dropped (integer arithmetic only). */
static size_t format_time(double value, char *out)
{
    if (!(value >= 0.0) || value > 9.0e15) {
        memcpy(out, "null", 4);
        return 4;
    }
    unsigned long long whole = (unsigned long long)value;
    unsigned long long nano = (unsigned long long)((value - (double)whole) * 1e9 + 0.5);
    if (nano >= 1000000000ULL) {
        whole += 1;
        nano -= 1000000000ULL;
    }
    char digits[24];
    size_t n = 0, len = 0;
    do {
        digits[n++] = (char)('0' + whole % 10);
        whole /= 10;
    } while (whole);
    while (n) out[len++] = digits[--n];
    out[len++] = '.';
    for (unsigned long long scale = 100000000ULL; scale; scale /= 10) out[len++] = (char)('0' + (nano / scale) % 10);
    while (out[len - 1] == '0' && out[len - 2] != '.') --len;
    return len;
}

static const char *name_of(int sig)
{
    switch (sig) {
    case SIGSEGV: return "SIGSEGV";
    case SIGBUS: return "SIGBUS";
    case SIGFPE: return "SIGFPE";
    case SIGILL: return "SIGILL";
    case SIGABRT: return "SIGABRT";
    default: return "a fatal signal";
    }
}

static void on_fatal(int sig)
{
    if (armed) {
        armed = 0;
        int fd = open(temporary, O_WRONLY | O_CREAT | O_TRUNC, 0644);
        if (fd >= 0) {
            const char *name = name_of(sig);
            char number[2][40];
            size_t number_len[2] = {format_time(progress[0], number[0]), format_time(progress[1], number[1])};
            size_t start = 0, ok = 1;
            for (size_t i = 0; i <= text_len && ok; ++i) {
                if (i == text_len || text[i] == '\x01' || text[i] == '\x02' || text[i] == '\x03') {
                    if (i > start && write(fd, text + start, i - start) < 0) ok = 0;
                    if (i < text_len) {
                        if (text[i] == '\x01') {
                            if (write(fd, name, strlen(name)) < 0) ok = 0;
                        } else {
                            int k = text[i] - '\x02';
                            if (write(fd, number[k], number_len[k]) < 0) ok = 0;
                        }
                    }
                    start = i + 1;
                }
            }
            close(fd);
            if (ok) rename(temporary, target);
            else unlink(temporary);
        }
    }
    for (size_t k = 0; k < N_WATCHED; ++k)
        if (watched[k] == sig) sigaction(sig, &previous[k], NULL);
    raise(sig);
}

/* Install the handler (once) for summaries written to ``path``; returns 0 on success. */
int crashguard_install(const char *path)
{
    size_t n = strlen(path);
    if (n + 5 > sizeof target) return 1;
    armed = 0;
    memcpy(target, path, n + 1);
    memcpy(temporary, path, n);
    memcpy(temporary + n, ".tmp", 5);
    if (installed) return 0;
    stack_t ss;
    ss.ss_sp = alt_stack;
    ss.ss_size = sizeof alt_stack;
    ss.ss_flags = 0;
    sigaltstack(&ss, NULL); /* a stack overflow can still be reported */
    struct sigaction action;
    memset(&action, 0, sizeof action);
    action.sa_handler = on_fatal;
    action.sa_flags = SA_ONSTACK;
    sigemptyset(&action.sa_mask);
    for (size_t k = 0; k < N_WATCHED; ++k)
        if (sigaction(watched[k], &action, &previous[k])) return 2;
    installed = 1;
    return 0;
}

/* The summary to write (signal name in place of each \x01); arms the handler. */
int crashguard_arm(const char *summary, size_t length)
{
    if (length > CAPACITY) return 1;
    armed = 0;
    memcpy(text, summary, length);
    text_len = length;
    armed = 1;
    return 0;
}

void crashguard_disarm(void) { armed = 0; }
