// A small self-written test harness: TEST(name) registers a case, CHECK* record failures
// without stopping the case. test_main.cpp runs every case and prints "N passed, M failed".
#ifndef AMZ_HOST_HARNESS_H
#define AMZ_HOST_HARNESS_H

#include <stdint.h>
#include <stdio.h>

namespace harness {

typedef void (*TestFn)(void* context);

// Register a case; the name and context must outlive the run. Returns a dummy for statics.
int register_test(const char* name, TestFn fn, void* context);
void fail(const char* file, int line, const char* expression, const char* detail);
// Checks so far in the running case that failed.
int failures_in_current();

}  // namespace harness

#define HARNESS_CAT2(a, b) a##b
#define HARNESS_CAT(a, b) HARNESS_CAT2(a, b)

#define TEST(name)                                                                  \
  static void test_##name(void*);                                                   \
  static int HARNESS_CAT(registered_, name) =                                       \
      harness::register_test(#name, &test_##name, 0);                               \
  static void test_##name(void*)

#define CHECK(cond)                                                                 \
  do {                                                                              \
    if (!(cond)) harness::fail(__FILE__, __LINE__, #cond, "");                      \
  } while (0)

#define CHECK_MSG(cond, msg)                                                        \
  do {                                                                              \
    if (!(cond)) harness::fail(__FILE__, __LINE__, #cond, (msg));                   \
  } while (0)

#define CHECK_EQ(a, b)                                                              \
  do {                                                                              \
    const long long harness_a = static_cast<long long>(a);                          \
    const long long harness_b = static_cast<long long>(b);                          \
    if (harness_a != harness_b) {                                                   \
      char harness_buf[96];                                                         \
      snprintf(harness_buf, sizeof harness_buf, "%lld != %lld", harness_a, harness_b); \
      harness::fail(__FILE__, __LINE__, #a " == " #b, harness_buf);                 \
    }                                                                               \
  } while (0)

#endif
