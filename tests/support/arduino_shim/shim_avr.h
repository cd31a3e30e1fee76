// sprintf as an 8-bit AVR runs it: arguments are pushed as the AVR promotes them (char and
// 16-bit types as a 2-byte int, 32-bit types as 4 bytes, little-endian) and the format reads
// that byte stream: %d/%u/%x/%c take 2 bytes, %ld/%lu 4, %s a pointer. Only what stand
// firmware uses; anything else aborts so a silent misprint cannot happen.
#pragma once

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <type_traits>
#include <vector>

struct ShimAvrArgs {
  std::vector<uint8_t> bytes;
  std::vector<const char*> strings;  // %s arguments, in order
};

template <class T>
void shim_avr_push(ShimAvrArgs& out, T value) {
  if constexpr (std::is_pointer_v<T>) {
    out.strings.push_back(reinterpret_cast<const char*>(value));
    out.bytes.push_back(0);
    out.bytes.push_back(0);  // an AVR pointer is 2 bytes
  } else {
    static_assert(std::is_integral_v<T>, "shim_avr_sprintf: integers and strings only");
    const size_t n = sizeof(T) <= 2 ? 2 : sizeof(T);  // promotion to a 16-bit int
    uint64_t v = static_cast<uint64_t>(static_cast<int64_t>(value));
    if constexpr (std::is_unsigned_v<T>) v = static_cast<uint64_t>(value);
    for (size_t i = 0; i < n; i++) out.bytes.push_back(static_cast<uint8_t>(v >> (8 * i)));
  }
}

int shim_avr_format(char* buf, const char* fmt, const ShimAvrArgs& args);

template <class... A>
int shim_avr_sprintf(char* buf, const char* fmt, A... args) {
  ShimAvrArgs packed;
  (shim_avr_push(packed, args), ...);
  return shim_avr_format(buf, fmt, packed);
}
