// pointviz — the C++ tests' one assertion: counts checks and failures, prints the failing
// condition with a printf-style note (the case to replay), and carries on.
#pragma once

#include <cstdio>

namespace pointviz_tests {
inline int g_checks = 0, g_failures = 0;
}  // namespace pointviz_tests

#define CHECK(cond, ...)                                                        \
    do {                                                                        \
        ++pointviz_tests::g_checks;                                             \
        if (!(cond)) {                                                          \
            ++pointviz_tests::g_failures;                                       \
            std::fprintf(stderr, "FAIL %s:%d: %s: ", __FILE__, __LINE__, #cond); \
            std::fprintf(stderr, __VA_ARGS__);                                  \
            std::fprintf(stderr, "\n");                                         \
        }                                                                       \
    } while (0)
