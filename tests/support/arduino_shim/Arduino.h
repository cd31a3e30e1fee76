// A small Arduino-API shim for compiling stand firmware for the host (thrustmap's own code;
// no Arduino core source is used). Serial is a pseudo-terminal; HX711 pins, analogRead and
// analogWrite talk to a harness process over stdin/stdout (see shim.cpp and harness.py);
// millis/micros come from CLOCK_MONOTONIC.
#pragma once

#include <math.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <string>

#define SHIM_VERSION "arduino-shim 2"

typedef uint8_t byte;
typedef bool boolean;

#define HIGH 1
#define LOW 0
#define INPUT 0
#define OUTPUT 1
#define INPUT_PULLUP 2

// Pins the two firmwares name: AVR analog pins and STM32 port pins.
enum ShimPins { A0 = 14, A1, A2, A3, A4, A5, PB8 = 40, PB9 };

#define constrain(x, lo, hi) ((x) < (lo) ? (lo) : ((x) > (hi) ? (hi) : (x)))
#define noInterrupts()
#define interrupts()

extern uint8_t TCCR1B;  // AVR timer register the tiny stand writes (no effect on the host)

unsigned long millis();
unsigned long micros();
void delay(unsigned long ms);
void delayMicroseconds(unsigned int us);
void yield();
void pinMode(uint8_t pin, uint8_t mode);
int digitalRead(uint8_t pin);
void digitalWrite(uint8_t pin, uint8_t value);
int analogRead(uint8_t pin);
void analogWrite(uint8_t pin, int value);
void HAL_NVIC_SystemReset();

class String {
 public:
  String() {}
  String(const char* s) : s_(s) {}
  String(const std::string& s) : s_(s) {}
  void trim();
  bool startsWith(const char* prefix) const { return s_.rfind(prefix, 0) == 0; }
  long toInt() const { return atol(s_.c_str()); }  // Arduino: atol, 0 when not a number
  const char* c_str() const { return s_.c_str(); }
  unsigned int length() const { return s_.size(); }

 private:
  std::string s_;
};

class ShimSerial {
 public:
  void begin(unsigned long baud);
  int available();
  int read();
  size_t write(uint8_t c);
  size_t print(const char* s);
  size_t println(const char* s);
  int printf(const char* fmt, ...) __attribute__((format(printf, 2, 3)));
  String readStringUntil(char terminator);
  void setTimeout(unsigned long ms) { timeout_ms_ = ms; }
  explicit operator bool() const { return true; }

 private:
  unsigned long timeout_ms_ = 1000;  // the Arduino Stream default
};

extern ShimSerial Serial;

#ifdef SHIM_AVR_INT16
// The AVR's int is 16 bits: a "%d" given a 32-bit argument prints its low 16 bits as a signed
// number (the argument's high half is never read). Rebuild the AVR's varargs from each
// argument's size and print through it (shim_avr.h).
#include "shim_avr.h"
#define sprintf shim_avr_sprintf
#endif
