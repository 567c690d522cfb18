// A stand-in for the few Arduino core calls hapticlab_master.ino makes, so the sketch builds with
// the host's g++ and runs as a process whose stdin/stdout is the serial port (see host.cpp).
// It checks the sketch's protocol logic; it is not an AVR build.
#pragma once
#include <math.h>
#include <stddef.h>
#include <stdint.h>

#define A2 16
#define HIGH 1
#define LOW 0
#define OUTPUT 1

void pinMode(uint8_t pin, uint8_t mode);
void digitalWrite(uint8_t pin, uint8_t value);
int analogRead(uint8_t pin);
void analogWrite(uint8_t pin, int value);
unsigned long micros();
unsigned long millis();

struct HostSerial {
  void begin(long baud);
  int available();
  int read();
  size_t write(const uint8_t *data, size_t n);
};
extern HostSerial Serial;
