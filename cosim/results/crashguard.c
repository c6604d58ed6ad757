/* Last words of a process that dies from a fatal signal: write a prepared summary.json.
 *
 * A crash in native code inside the run's process (an FMU dereferencing NULL, calling abort(),
 * a bug in a compiled helper) ends the process before Python can write anything. This handler,
 * installed for SIGSEGV, SIGBUS, SIGFPE, SIGILL and SIGABRT, writes a summary that Python prepared
 * beforehand (status "failed", the run's last known progress) with the signal's name in place of
 * every \x01 byte, using only async-signal-safe calls (open, write, close, rename), then hands the
 * signal to the previous handler (or the default action) so the process still dies from it. */
#define _XOPEN_SOURCE 700 /* sigaction, sigaltstack, SA_ONSTACK under -std=c99 */
#include <fcntl.h>
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
            size_t start = 0, ok = 1;
            for (size_t i = 0; i <= text_len && ok; ++i) {
                if (i == text_len || text[i] == '\x01') {
                    if (i > start && write(fd, text + start, i - start) < 0) ok = 0;
                    if (i < text_len && write(fd, name, strlen(name)) < 0) ok = 0;
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
