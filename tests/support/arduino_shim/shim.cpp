// The host side of the Arduino shim: main() runs setup() then loop() forever.
//
// Serial: a pseudo-terminal; its slave path is announced on stdout as "PTY <path>" and the
// host program (thrustmap) opens it. Control protocol with the harness (one line each):
//   harness -> shim (stdin):  "HX <signed 24-bit>"   the HX711's next conversion
//                              "ADC <pin> <0..1023>"  what analogRead(pin) returns
//                              "RESET"                the MCU resets (its DTR reset line):
//                              the process re-executes itself on the same pseudo-terminal
//   shim -> harness (stdout): "PTY <path>", "PWM <pin> <value>" (analogWrite),
//                              "RX <text>" (a line the firmware received), "RESET"
// SHIM_BOOT_S: after a (re)start the board hears nothing for this long (a bootloader).
// The HX711 is emulated at its pins: DOUT low when a conversion is ready (SHIM_HX711_SPS,
// default 10/s), 24 bits MSB first on SCK rising edges, then the gain pulses.
#include <errno.h>
#include <fcntl.h>
#include <pthread.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <atomic>
#include <string>

#include "Arduino.h"
#include "shim_avr.h"

void setup();
void loop();

uint8_t TCCR1B = 0;
ShimSerial Serial;

static int g_master = -1;
static struct timespec g_start;
static std::atomic<long> g_hx_value{0};
static std::atomic<int> g_adc[8];
static pthread_mutex_t g_out = PTHREAD_MUTEX_INITIALIZER;

static void control(const char* fmt, ...) __attribute__((format(printf, 1, 2)));
static void control(const char* fmt, ...) {
  pthread_mutex_lock(&g_out);
  va_list ap;
  va_start(ap, fmt);
  vfprintf(stdout, fmt, ap);
  va_end(ap);
  fputc('\n', stdout);
  fflush(stdout);
  pthread_mutex_unlock(&g_out);
}

// ------------------------------------------------------------------------------ time
static uint64_t now_us() {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (uint64_t)(t.tv_sec - g_start.tv_sec) * 1000000ull + (t.tv_nsec - g_start.tv_nsec) / 1000;
}
static void sleep_us(long us) {
  struct timespec t = {us / 1000000, (us % 1000000) * 1000};
  nanosleep(&t, nullptr);
}
unsigned long millis() { return (unsigned long)(uint32_t)(now_us() / 1000); }
unsigned long micros() { return (unsigned long)(uint32_t)now_us(); }
void delay(unsigned long ms) { sleep_us((long)ms * 1000); }
void delayMicroseconds(unsigned int) {}  // bit-bang delays: the emulated HX711 needs none
void yield() { sleep_us(100); }

// ------------------------------------------------------------------------------ HX711
static int g_hx_dout_pin = -1, g_hx_sck_pin = -1;
static uint64_t g_hx_next_us = 0;  // when the next conversion is ready
static bool g_hx_ready = false, g_hx_reading = false;
static uint32_t g_hx_word = 0;
static int g_hx_bit = 0;

static uint64_t hx_period_us() {
  const char* sps = getenv("SHIM_HX711_SPS");
  double rate = sps ? atof(sps) : 10.0;
  return (uint64_t)(1e6 / (rate > 0 ? rate : 10.0));
}

static void hx_poll() {
  if (!g_hx_ready && !g_hx_reading && now_us() >= g_hx_next_us) {
    g_hx_ready = true;
    g_hx_word = (uint32_t)g_hx_value.load() & 0xFFFFFFu;
    g_hx_bit = 0;
  }
}

static int hx_dout() {
  hx_poll();
  if (g_hx_reading) return g_hx_bit >= 1 && g_hx_bit <= 24 ? (g_hx_word >> (24 - g_hx_bit)) & 1 : 1;
  if (!g_hx_ready) sleep_us(200);  // a firmware spinning on DOUT: do not burn the CPU
  return g_hx_ready ? 0 : 1;
}

static void hx_sck_rising() {
  if (g_hx_ready && !g_hx_reading) {
    g_hx_reading = true;
    g_hx_ready = false;
    g_hx_bit = 0;
  }
  if (!g_hx_reading) return;
  g_hx_bit++;
  if (g_hx_bit >= 25) {  // the 25th pulse: gain 128 on channel A, the next conversion starts
    g_hx_reading = false;
    g_hx_next_us = now_us() + hx_period_us();
  }
}

// ------------------------------------------------------------------------------ pins
static int g_pin_mode[64];
static int g_pin_level[64];
void pinMode(uint8_t pin, uint8_t mode) {
  if (pin < 64) g_pin_mode[pin] = mode;
}
int digitalRead(uint8_t pin) {
  if (g_hx_dout_pin < 0 && pin < 64 && g_pin_mode[pin] == INPUT) g_hx_dout_pin = pin;
  return pin == g_hx_dout_pin ? hx_dout() : 0;
}
void digitalWrite(uint8_t pin, uint8_t value) {
  if (pin >= 64) return;
  const char* hx_sck = getenv("SHIM_HX711_SCK");
  if (hx_sck && atoi(hx_sck) == pin) g_hx_sck_pin = pin;
  if (pin == g_hx_sck_pin && value && !g_pin_level[pin]) hx_sck_rising();
  g_pin_level[pin] = value ? 1 : 0;
}
int analogRead(uint8_t pin) { return pin >= A0 && pin < A0 + 8 ? g_adc[pin - A0].load() : 0; }
void analogWrite(uint8_t pin, int value) { control("PWM %d %d", pin, value); }
void HAL_NVIC_SystemReset() {
  control("RESET");
  exit(3);
}

// ------------------------------------------------------------------------------ String
void String::trim() {
  size_t a = s_.find_first_not_of(" \t\r\n"), b = s_.find_last_not_of(" \t\r\n");
  s_ = a == std::string::npos ? std::string() : s_.substr(a, b - a + 1);
}

// ------------------------------------------------------------------------------ Serial
static std::string g_rx;      // bytes from the host not yet read by the firmware
static std::string g_rxline;  // for the "RX" report to the harness

static void serial_pump() {
  char buf[256];
  for (;;) {
    ssize_t n = ::read(g_master, buf, sizeof buf);
    if (n <= 0) break;
    for (ssize_t i = 0; i < n; i++) {
      g_rx.push_back(buf[i]);
      if (buf[i] == '\n' || buf[i] == '\r') {
        if (!g_rxline.empty()) control("RX %s", g_rxline.c_str());
        g_rxline.clear();
      } else if (g_rxline.size() < 200) {
        g_rxline.push_back(buf[i]);
      }
    }
  }
}

void ShimSerial::begin(unsigned long) {}
int ShimSerial::available() {
  serial_pump();
  if (g_rx.empty()) sleep_us(500);  // a firmware polling Serial: do not burn the CPU
  return (int)g_rx.size();
}
int ShimSerial::read() {
  serial_pump();
  if (g_rx.empty()) return -1;
  int c = (uint8_t)g_rx[0];
  g_rx.erase(0, 1);
  return c;
}
size_t ShimSerial::write(uint8_t c) {
  while (::write(g_master, &c, 1) < 0 && errno == EAGAIN) sleep_us(200);
  return 1;
}
size_t ShimSerial::print(const char* s) {
  size_t n = strlen(s), done = 0;
  while (done < n) {
    ssize_t w = ::write(g_master, s + done, n - done);
    if (w > 0) done += (size_t)w;
    else if (errno == EAGAIN) sleep_us(200);
    else break;
  }
  return n;
}
size_t ShimSerial::println(const char* s) { return print(s) + print("\r\n"); }
int ShimSerial::printf(const char* fmt, ...) {
  char buf[512];
  va_list ap;
  va_start(ap, fmt);
  int n = vsnprintf(buf, sizeof buf, fmt, ap);
  va_end(ap);
  print(buf);
  return n;
}
String ShimSerial::readStringUntil(char terminator) {
  std::string out;
  uint64_t deadline = now_us() + (uint64_t)timeout_ms_ * 1000;
  for (;;) {
    int c = read();
    if (c == terminator) break;
    if (c >= 0) {
      out.push_back((char)c);
      deadline = now_us() + (uint64_t)timeout_ms_ * 1000;
    } else if (now_us() >= deadline) {
      break;
    } else {
      sleep_us(200);
    }
  }
  return String(out);
}

// ------------------------------------------------------------------------------ AVR sprintf
int shim_avr_format(char* buf, const char* fmt, const ShimAvrArgs& args) {
  size_t at = 0, s_at = 0;
  char* out = buf;
  auto take = [&](size_t n) {
    uint32_t v = 0;
    for (size_t i = 0; i < n; i++) v |= (uint32_t)(at + i < args.bytes.size() ? args.bytes[at + i] : 0) << (8 * i);
    at += n;
    return v;
  };
  for (const char* p = fmt; *p; p++) {
    if (*p != '%') {
      *out++ = *p;
      continue;
    }
    bool is_long = false;
    p++;
    if (*p == 'l') {
      is_long = true;
      p++;
    }
    switch (*p) {
      case '%': *out++ = '%'; break;
      case 'd': out += is_long ? sprintf(out, "%ld", (long)(int32_t)take(4)) : sprintf(out, "%d", (int)(int16_t)take(2)); break;
      case 'u': out += is_long ? sprintf(out, "%lu", (unsigned long)take(4)) : sprintf(out, "%u", (unsigned)(uint16_t)take(2)); break;
      case 'c': *out++ = (char)take(2); break;
      case 's': take(2); out += sprintf(out, "%s", s_at < args.strings.size() ? args.strings[s_at++] : ""); break;
      default: fprintf(stderr, "shim_avr_sprintf: unsupported %%%c\n", *p); abort();
    }
  }
  *out = 0;
  return (int)(out - buf);
}

// ------------------------------------------------------------------------------ harness link
static char** g_argv;
static int g_keep = -1;

static void reset_mcu() {  // a reset runs the firmware from setup() again, on the same port
  char fds[64];
  snprintf(fds, sizeof fds, "%d %d", g_master, g_keep);
  setenv("SHIM_PTY_FDS", fds, 1);
  control("RESET");
  execv("/proc/self/exe", g_argv);
  _exit(4);
}

static void* control_reader(void*) {
  char line[128];
  while (fgets(line, sizeof line, stdin)) {
    long a = 0, b = 0;
    if (strncmp(line, "RESET", 5) == 0) reset_mcu();
    if (sscanf(line, "HX %ld", &a) == 1) g_hx_value.store(a);
    else if (sscanf(line, "ADC %ld %ld", &a, &b) == 2 && a >= A0 && a < A0 + 8) g_adc[a - A0].store((int)b);
  }
  exit(0);  // the harness is gone
}

int main(int, char** argv) {
  g_argv = argv;
  clock_gettime(CLOCK_MONOTONIC, &g_start);
  const char* fds = getenv("SHIM_PTY_FDS");
  if (fds && sscanf(fds, "%d %d", &g_master, &g_keep) == 2) {
    // after a reset: the same pseudo-terminal
  } else {
    g_master = posix_openpt(O_RDWR | O_NOCTTY);
    if (g_master < 0 || grantpt(g_master) || unlockpt(g_master)) return 2;
    g_keep = open(ptsname(g_master), O_RDWR | O_NOCTTY);  // held: no EIO while the host reopens
    struct termios tio;
    tcgetattr(g_keep, &tio);
    cfmakeraw(&tio);
    tcsetattr(g_keep, TCSANOW, &tio);
    fcntl(g_master, F_SETFL, fcntl(g_master, F_GETFL) | O_NONBLOCK);
  }
  const char* slave = ptsname(g_master);
  pthread_t reader;
  pthread_create(&reader, nullptr, control_reader, nullptr);
  control("PTY %s", slave);
  control("SHIM %s", SHIM_VERSION);
  const char* boot = getenv("SHIM_BOOT_S");
  if (boot && atof(boot) > 0) {  // the bootloader: what arrives meanwhile is lost
    sleep_us((long)(atof(boot) * 1e6));
    char junk[256];
    while (::read(g_master, junk, sizeof junk) > 0) {
    }
  }
  setup();
  for (;;) {
    loop();
    hx_poll();
    sleep_us(100);  // between loop() runs: a busy firmware loop would take a whole core
  }
}
