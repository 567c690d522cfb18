// Runs hapticlab_master.ino on the host: Serial is stdin/stdout, the handle sensor reads a fixed
// count (ADC_COUNT, default 600), and every motor PWM change is logged to stderr as "pwm <dir> <duty>".
#include "Arduino.h"

#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include <unistd.h>

HostSerial Serial;
static int next_byte = -1;
static int direction = 0;

void pinMode(uint8_t, uint8_t) {}
void digitalWrite(uint8_t, uint8_t value) { direction = value; }
int analogRead(uint8_t) {
  const char *count = getenv("ADC_COUNT");
  return count ? atoi(count) : 600;
}
void analogWrite(uint8_t, int value) {
  fprintf(stderr, "pwm %d %d\n", direction, value);
  fflush(stderr);
}

static unsigned long now_us() {
  timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (unsigned long)t.tv_sec * 1000000UL + (unsigned long)(t.tv_nsec / 1000);
}
unsigned long micros() { return now_us(); }
unsigned long millis() { return now_us() / 1000; }

void HostSerial::begin(long) {}
int HostSerial::available() {
  if (next_byte >= 0) return 1;
  pollfd p = {0, POLLIN, 0};
  unsigned char c;
  if (poll(&p, 1, 1) > 0 && ::read(0, &c, 1) == 1) next_byte = c;
  if (p.revents & (POLLHUP | POLLERR)) exit(0);
  return next_byte >= 0;
}
int HostSerial::read() {
  int c = next_byte;
  next_byte = -1;
  return c;
}
size_t HostSerial::write(const uint8_t *data, size_t n) { return (size_t)::write(1, data, n); }

void setup();
void loop();

int main() {
  setup();
  for (;;) loop();
}
