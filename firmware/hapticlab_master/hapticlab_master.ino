// hapticlab_master.ino: the device side of the hapticlab serial master protocol, version 1.
//
// Specification: docs/serial-protocol.md. Host: the `serial` haptic output
// plugin with protocol = "hapticlab". Emulated device (the same behaviour, for
// tests): plugins/haptics/master_emulator.py.
//
// Written for a one-axis Hapkit-class master on an Arduino Uno (ATmega328P,
// 16 MHz): a magnetoresistive sensor on the capstan gives the handle angle,
// one DC motor (PWM + direction) gives the force. The protocol side (framing,
// CRC, handshake, sequence numbers, watchdog, clamp) does not depend on the
// hardware; the three functions in the HARDWARE section do, and carry the
// calibration a builder must redo for their own device. More axes: fill the y
// and z components in readHandle() and renderForce().
//
// Not compiled in hapticlab's test suite (no Arduino toolchain there); it uses
// only the Arduino core API (Serial, analogRead, analogWrite, digitalWrite,
// micros, millis).

#include <Arduino.h>
#include <string.h>

// ------------------------------------------------------------------ protocol constants

static const uint8_t PROTOCOL_VERSION = 1;
static const uint8_t SYNC1 = 0xA5, SYNC2 = 0x5A;
static const uint8_t MAX_PAYLOAD = 64;

static const uint8_t T_HELLO = 0x01, T_FORCE = 0x02, T_HEARTBEAT = 0x03;
static const uint8_t T_HELLO_ACK = 0x81, T_STATE = 0x82, T_NAK = 0xFF;

static const uint8_t NAK_CRC = 1, NAK_UNKNOWN_TYPE = 2, NAK_BAD_LENGTH = 3, NAK_VERSION = 4, NAK_NOT_READY = 5;

static const uint8_t STATUS_WATCHDOG = 1 << 0, STATUS_CLAMPED = 1 << 1, STATUS_FAULT = 1 << 2;

static const uint16_t DEVICE_ID = 0x4B31;  // pick your own
static const uint8_t FIRMWARE_VERSION = 1;
static const float MAX_FORCE_N = 3.0f;      // what this device can render, N
static const float MAX_RATE_HZ = 1000.0f;   // the command rate it keeps up with, Hz
static const long BAUD = 1000000L;          // 1 Mbit/s: a 1 kHz exchange needs > 540 kbit/s

// ------------------------------------------------------------------ HARDWARE (calibrate for your device)

static const uint8_t PIN_SENSOR = A2;   // MR sensor on the capstan
static const uint8_t PIN_PWM = 5;       // motor driver PWM
static const uint8_t PIN_DIR = 8;       // motor driver direction
static const float METRES_PER_COUNT = 0.00012f;  // handle displacement per ADC count (calibrate)
static const int ZERO_COUNT = 512;              // ADC count at the handle's centre (calibrate)
static const float NEWTONS_AT_FULL_PWM = 3.2f;  // handle force at PWM 255 (calibrate)
static const float VELOCITY_FILTER = 0.2f;      // first-order low-pass on the differentiated position

static float handle_x = 0.0f, handle_vx = 0.0f;
static unsigned long last_read_us = 0;

// Read the handle: position (m) and velocity (m/s) in the device frame D.
static void readHandle(float p[3], float v[3]) {
  unsigned long now = micros();
  float x = (analogRead(PIN_SENSOR) - ZERO_COUNT) * METRES_PER_COUNT;
  float dt = (now - last_read_us) * 1e-6f;
  if (last_read_us != 0 && dt > 0.0f) {
    handle_vx += VELOCITY_FILTER * ((x - handle_x) / dt - handle_vx);
  }
  handle_x = x;
  last_read_us = now;
  p[0] = handle_x; p[1] = 0.0f; p[2] = 0.0f;
  v[0] = handle_vx; v[1] = 0.0f; v[2] = 0.0f;
}

// Render a force (N, in D) that is already finite and within MAX_FORCE_N.
static void renderForce(const float f[3]) {
  float duty = f[0] / NEWTONS_AT_FULL_PWM;
  digitalWrite(PIN_DIR, duty < 0.0f ? HIGH : LOW);
  duty = fabs(duty);
  if (duty > 1.0f) duty = 1.0f;
  analogWrite(PIN_PWM, (int)(duty * 255.0f + 0.5f));
}

// Buttons pressed, one bit each (none on a plain Hapkit).
static uint16_t readButtons() { return 0; }

// ------------------------------------------------------------------ CRC-16/CCITT-FALSE

static uint16_t crc16(const uint8_t *data, uint8_t n, uint16_t crc = 0xFFFF) {
  for (uint8_t i = 0; i < n; i++) {
    crc ^= (uint16_t)data[i] << 8;
    for (uint8_t b = 0; b < 8; b++) crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x1021) : (uint16_t)(crc << 1);
  }
  return crc;
}

// ------------------------------------------------------------------ sending

static uint8_t tx_seq = 0;
static uint8_t pending_status = 0;

static void sendFrame(uint8_t type, const uint8_t *payload, uint8_t len) {
  uint8_t head[5] = {SYNC1, SYNC2, type, ++tx_seq, len};
  uint16_t crc = crc16(head + 2, 3);
  crc = crc16(payload, len, crc);
  uint8_t tail[2] = {(uint8_t)(crc & 0xFF), (uint8_t)(crc >> 8)};
  Serial.write(head, 5);
  if (len) Serial.write(payload, len);
  Serial.write(tail, 2);
}

static void sendNak(uint8_t seq, uint8_t code) {
  uint8_t payload[2] = {seq, code};
  sendFrame(T_NAK, payload, 2);
}

static void sendHelloAck() {
  uint8_t payload[12];
  payload[0] = PROTOCOL_VERSION;
  payload[1] = DEVICE_ID & 0xFF;
  payload[2] = DEVICE_ID >> 8;
  payload[3] = FIRMWARE_VERSION;
  memcpy(payload + 4, &MAX_FORCE_N, 4);  // AVR and ARM are little-endian IEEE-754: the wire's layout
  memcpy(payload + 8, &MAX_RATE_HZ, 4);
  sendFrame(T_HELLO_ACK, payload, 12);
}

static void sendState(uint8_t ack_seq) {
  float p[3], v[3];
  readHandle(p, v);
  uint16_t buttons = readButtons();
  uint8_t payload[28];
  payload[0] = ack_seq;
  memcpy(payload + 1, p, 12);
  memcpy(payload + 13, v, 12);
  payload[25] = buttons & 0xFF;
  payload[26] = buttons >> 8;
  payload[27] = pending_status;
  pending_status = 0;  // each bit is reported once
  sendFrame(T_STATE, payload, 28);
}

// ------------------------------------------------------------------ the device's state

static bool hello_done = false;
static uint16_t watchdog_ms = 0;
static unsigned long last_valid_ms = 0;
static bool force_on = false;

static void zeroForce() {
  static const float zero[3] = {0.0f, 0.0f, 0.0f};
  renderForce(zero);
  force_on = false;
}

static void applyForce(const uint8_t *payload) {
  float f[3];
  memcpy(f, payload, 12);
  float n2 = f[0] * f[0] + f[1] * f[1] + f[2] * f[2];
  if (!(n2 == n2) || isinf(n2)) {  // NaN or infinite: nothing but zero is safe
    zeroForce();
    return;
  }
  if (n2 > MAX_FORCE_N * MAX_FORCE_N) {
    float k = MAX_FORCE_N / sqrt(n2);
    f[0] *= k; f[1] *= k; f[2] *= k;
    pending_status |= STATUS_CLAMPED;
  }
  renderForce(f);
  force_on = (n2 > 0.0f);
}

static void onFrame(uint8_t type, uint8_t seq, const uint8_t *payload, uint8_t len) {
  switch (type) {
    case T_HELLO:
      if (len != 3) { sendNak(seq, NAK_BAD_LENGTH); return; }
      if (payload[0] != PROTOCOL_VERSION) { sendNak(seq, NAK_VERSION); return; }
      watchdog_ms = payload[1] | ((uint16_t)payload[2] << 8);
      hello_done = true;
      last_valid_ms = millis();
      zeroForce();
      sendHelloAck();
      return;
    case T_FORCE:
    case T_HEARTBEAT:
      if (len != (type == T_FORCE ? 12 : 0)) { sendNak(seq, NAK_BAD_LENGTH); return; }
      if (!hello_done) { sendNak(seq, NAK_NOT_READY); return; }
      last_valid_ms = millis();
      if (type == T_FORCE) applyForce(payload);
      sendState(seq);
      return;
    default:
      sendNak(seq, NAK_UNKNOWN_TYPE);
  }
}

// ------------------------------------------------------------------ receiving: find frames in the byte stream

static uint8_t rx[5 + MAX_PAYLOAD + 2];
static uint8_t rx_len = 0;

// Drop the first n bytes of the receive buffer.
static void rxDrop(uint8_t n) {
  memmove(rx, rx + n, rx_len - n);
  rx_len -= n;
}

// Decode every complete frame in the buffer; on a bad length or CRC, resume the hunt one byte on.
static void rxParse() {
  for (;;) {
    uint8_t i = 0;
    while (i + 1 < rx_len && !(rx[i] == SYNC1 && rx[i + 1] == SYNC2)) i++;
    if (i + 1 >= rx_len) {  // no sync pair: keep a trailing 0xA5, it may be half of one
      bool keep = rx_len && rx[rx_len - 1] == SYNC1;
      rxDrop(rx_len - (keep ? 1 : 0));
      return;
    }
    if (i) rxDrop(i);
    if (rx_len < 5) return;
    uint8_t len = rx[4];
    if (len > MAX_PAYLOAD) { rxDrop(1); continue; }
    uint8_t total = 5 + len + 2;
    if (rx_len < total) return;
    uint16_t crc = crc16(rx + 2, 3 + len);
    uint16_t sent = rx[5 + len] | ((uint16_t)rx[6 + len] << 8);
    if (crc != sent) {
      sendNak(0, NAK_CRC);
      rxDrop(1);
      continue;
    }
    onFrame(rx[2], rx[3], rx + 5, len);
    rxDrop(total);
  }
}

// ------------------------------------------------------------------ setup and loop

void setup() {
  pinMode(PIN_PWM, OUTPUT);
  pinMode(PIN_DIR, OUTPUT);
  zeroForce();
  Serial.begin(BAUD);
}

void loop() {
  while (Serial.available() && rx_len < sizeof(rx)) {
    rx[rx_len++] = (uint8_t)Serial.read();
    if (rx_len >= 5) rxParse();
  }
  if (rx_len == sizeof(rx)) rxDrop(1);  // a full buffer without a frame: garbage

  // the watchdog: no valid host frame for watchdog_ms → no force
  if (hello_done && watchdog_ms && force_on && (unsigned long)(millis() - last_valid_ms) > watchdog_ms) {
    zeroForce();
    pending_status |= STATUS_WATCHDOG;
  }
}
