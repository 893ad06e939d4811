#pragma once
/// Marks the compiled libraries' public API (they are built with hidden visibility).
#define PERCH2_API __attribute__((visibility("default")))
