#include <stdio.h>
#include <string.h>

#include "harness.h"

namespace harness {
namespace {

struct Case {
  const char* name;
  TestFn fn;
  void* context;
};

const int kMaxCases = 512;
Case g_cases[kMaxCases];
int g_count = 0;
int g_dropped = 0;  // cases refused for want of room: the run fails, it must not pass short
int g_current_failures = 0;
const char* g_current_name = "";

}  // namespace

int register_test(const char* name, TestFn fn, void* context) {
  if (g_count == kMaxCases) {
    fprintf(stderr, "too many test cases: %s not registered (raise kMaxCases)\n", name);
    ++g_dropped;
    return 0;
  }
  g_cases[g_count].name = name;
  g_cases[g_count].fn = fn;
  g_cases[g_count].context = context;
  ++g_count;
  return g_count;
}

void fail(const char* file, int line, const char* expression, const char* detail) {
  ++g_current_failures;
  printf("  FAIL %s (%s:%d): %s %s\n", g_current_name, file, line, expression, detail);
}

int failures_in_current() { return g_current_failures; }

}  // namespace harness

void register_vector_tests();

int main(int argc, char** argv) {
  register_vector_tests();
  const char* filter = argc > 1 ? argv[1] : 0;
  int passed = 0;
  int failed = 0;
  for (int i = 0; i < harness::g_count; ++i) {
    const harness::Case& c = harness::g_cases[i];
    if (filter != 0 && strstr(c.name, filter) == 0) continue;
    harness::g_current_name = c.name;
    harness::g_current_failures = 0;
    c.fn(c.context);
    if (harness::g_current_failures == 0) {
      ++passed;
    } else {
      ++failed;
      printf("FAILED %s\n", c.name);
    }
  }
  printf("%d passed, %d failed\n", passed, failed);
  if (harness::g_dropped > 0) {
    printf("%d cases not run: more than %d registered\n", harness::g_dropped, harness::kMaxCases);
    return 1;
  }
  return failed == 0 && passed > 0 ? 0 : 1;
}
