// The goburrow/modbus adapter of `mbconform client` (protocol 1,
// conformance/client/README.md): Debian's golang-github-goburrow-modbus-dev
// (0.1.0) through its Client interface, as its README shows. The package has
// no FC 43 call and no raw PDU, and no RTU over TCP: those ops are not listed
// and "rtu-tcp" answers ready: false. One JSON object a line on stdin, one
// answer a line on stdout; the package's transmission log goes to stderr.
//
// Built offline in GOPATH mode with Debian's Go (conformance/peers/adapters/CMakeLists.txt):
//   GO111MODULE=off GOPATH=/usr/share/gocode GOPROXY=off go build -o goburrow_adapter goburrow_adapter.go
package main

import (
	"bufio"
	"encoding/binary"
	"encoding/json"
	"errors"
	"fmt"
	"io"
	"log"
	"net"
	"os"
	"strings"
	"time"

	"github.com/goburrow/modbus"
	"github.com/goburrow/serial"
)

const protocol = 1

// The version of Debian's package (the Go package itself records none), set
// by the build: -ldflags "-X main.version=...".
var version = "unknown"

var ops = []string{"read_coils", "read_discrete_inputs", "read_holding_registers", "read_input_registers",
	"write_single_coil", "write_single_register", "write_multiple_coils", "write_multiple_registers",
	"mask_write_register", "read_write_multiple_registers"}

type request struct {
	ID           int      `json:"id"`
	Op           string   `json:"op"`
	Unit         *int     `json:"unit"`
	Address      uint16   `json:"address"`
	Count        uint16   `json:"count"`
	Value        any      `json:"value"`
	Values       []any    `json:"values"`
	AndMask      uint16   `json:"and_mask"`
	OrMask       uint16   `json:"or_mask"`
	ReadAddress  uint16   `json:"read_address"`
	ReadCount    uint16   `json:"read_count"`
	WriteAddress uint16   `json:"write_address"`
	Hello        any      `json:"hello"`
	Connect      *connect `json:"connect"`
	Disconnect   bool     `json:"disconnect"`
}

type connect struct {
	Transport string `json:"transport"`
	Host      string `json:"host"`
	Port      int    `json:"port"`
	Device    string `json:"device"`
	Baud      int    `json:"baud"`
	Parity    string `json:"parity"`
	Data      int    `json:"data"`
	Stop      int    `json:"stop"`
	TimeoutMs int    `json:"timeout_ms"`
}

// One connection: the handler (whose SlaveId is set per request) and its client.
type session struct {
	tcp    *modbus.TCPClientHandler
	rtu    *modbus.RTUClientHandler
	client modbus.Client
}

func (s *session) close() {
	if s.tcp != nil {
		s.tcp.Close()
	}
	if s.rtu != nil {
		s.rtu.Close()
	}
	*s = session{}
}

func (s *session) open(c *connect) map[string]any {
	s.close()
	timeout := time.Duration(c.TimeoutMs) * time.Millisecond
	logger := log.New(os.Stderr, "goburrow: ", log.Lmicroseconds)
	switch c.Transport {
	case "tcp":
		h := modbus.NewTCPClientHandler(fmt.Sprintf("%s:%d", c.Host, c.Port))
		h.Timeout = timeout
		h.Logger = logger
		if err := h.Connect(); err != nil {
			return map[string]any{"ready": false, "detail": err.Error()}
		}
		s.tcp, s.client = h, modbus.NewClient(h)
	case "rtu":
		h := modbus.NewRTUClientHandler(c.Device)
		h.Config = serial.Config{Address: c.Device, BaudRate: c.Baud, DataBits: c.Data, StopBits: c.Stop, Parity: c.Parity, Timeout: timeout}
		h.Logger = logger
		if err := h.Connect(); err != nil {
			return map[string]any{"ready": false, "detail": err.Error()}
		}
		s.rtu, s.client = h, modbus.NewClient(h)
	default:
		return map[string]any{"ready": false, "detail": "goburrow/modbus has no transport " + c.Transport}
	}
	// goburrow/modbus sends each request once: there are no retries to turn off.
	return map[string]any{"ready": true}
}

func (s *session) setUnit(unit byte) {
	if s.tcp != nil {
		s.tcp.SlaveId = unit
	} else if s.rtu != nil {
		s.rtu.SlaveId = unit
	}
}

func words(values []any) []byte {
	b := make([]byte, 2*len(values))
	for i, v := range values {
		binary.BigEndian.PutUint16(b[2*i:], uint16(v.(float64)))
	}
	return b
}

func truthy(v any) bool {
	switch x := v.(type) {
	case bool:
		return x
	case float64:
		return x != 0
	}
	return false
}

func bits(values []any) []byte {
	b := make([]byte, (len(values)+7)/8)
	for i, v := range values {
		if truthy(v) {
			b[i/8] |= 1 << (i % 8)
		}
	}
	return b
}

func unpackBits(b []byte, n int) []any {
	out := []any{}
	for i := 0; i < n && i/8 < len(b); i++ {
		out = append(out, b[i/8]&(1<<(i%8)) != 0)
	}
	return out
}

func unpackWords(b []byte) []any {
	out := []any{}
	for i := 0; i+1 < len(b); i += 2 {
		out = append(out, binary.BigEndian.Uint16(b[i:]))
	}
	return out
}

// call runs one op; values are what the protocol reports on success.
func (s *session) call(r *request) ([]any, error) {
	c := s.client
	switch r.Op {
	case "read_coils":
		b, err := c.ReadCoils(r.Address, r.Count)
		return unpackBits(b, int(r.Count)), err
	case "read_discrete_inputs":
		b, err := c.ReadDiscreteInputs(r.Address, r.Count)
		return unpackBits(b, int(r.Count)), err
	case "read_holding_registers":
		b, err := c.ReadHoldingRegisters(r.Address, r.Count)
		return unpackWords(b), err
	case "read_input_registers":
		b, err := c.ReadInputRegisters(r.Address, r.Count)
		return unpackWords(b), err
	case "write_single_coil":
		v := uint16(0x0000)
		if truthy(r.Value) {
			v = 0xFF00
		}
		_, err := c.WriteSingleCoil(r.Address, v)
		return []any{}, err
	case "write_single_register":
		_, err := c.WriteSingleRegister(r.Address, uint16(r.Value.(float64)))
		return []any{}, err
	case "write_multiple_coils":
		_, err := c.WriteMultipleCoils(r.Address, uint16(len(r.Values)), bits(r.Values))
		return []any{}, err
	case "write_multiple_registers":
		_, err := c.WriteMultipleRegisters(r.Address, uint16(len(r.Values)), words(r.Values))
		return []any{}, err
	case "mask_write_register":
		_, err := c.MaskWriteRegister(r.Address, r.AndMask, r.OrMask)
		return []any{}, err
	case "read_write_multiple_registers":
		b, err := c.ReadWriteMultipleRegisters(r.ReadAddress, r.ReadCount, r.WriteAddress, uint16(len(r.Values)), words(r.Values))
		return unpackWords(b), err
	}
	return nil, errUnsupported
}

var errUnsupported = errors.New("unsupported")

// failure puts the package's error in the protocol's words. The package's
// own checks are fmt.Errorf strings: "must be between" before sending,
// "does not match" / "response ..." on a reply it rejects.
func failure(id int, err error) map[string]any {
	msg := err.Error()
	var me *modbus.ModbusError
	var ne net.Error
	switch {
	case errors.Is(err, errUnsupported):
		return map[string]any{"id": id, "ok": false, "error": "unsupported"}
	case errors.As(err, &me):
		return map[string]any{"id": id, "ok": false, "error": "exception", "code": me.ExceptionCode}
	case errors.As(err, &ne) && ne.Timeout(), errors.Is(err, serial.ErrTimeout):
		return map[string]any{"id": id, "ok": false, "error": "timeout", "detail": msg}
	case errors.Is(err, io.EOF), errors.Is(err, io.ErrUnexpectedEOF):
		return map[string]any{"id": id, "ok": false, "error": "timeout", "detail": "no complete reply: " + msg}
	case strings.Contains(msg, "must be between") || strings.Contains(msg, "must not be"):
		return map[string]any{"id": id, "ok": false, "error": "refused", "detail": msg}
	case strings.Contains(msg, "does not match") || strings.Contains(msg, "response") || strings.Contains(msg, "crc"):
		return map[string]any{"id": id, "ok": false, "error": "invalid_reply", "detail": msg}
	}
	return map[string]any{"id": id, "ok": false, "error": "other", "detail": msg}
}

func contains(list []string, s string) bool {
	for _, x := range list {
		if x == s {
			return true
		}
	}
	return false
}

func main() {
	in := bufio.NewScanner(os.Stdin)
	in.Buffer(make([]byte, 1<<20), 1<<20)
	out := json.NewEncoder(os.Stdout) // one object a line; os.Stdout is unbuffered
	var s session
	defer s.close()
	for in.Scan() {
		var r request
		if err := json.Unmarshal(in.Bytes(), &r); err != nil {
			fmt.Fprintf(os.Stderr, "goburrow adapter: not JSON: %s\n", in.Text())
			continue
		}
		switch {
		case r.Hello != nil:
			out.Encode(map[string]any{"protocol": protocol, "library": "goburrow/modbus", "version": version,
				"ops": ops, "raw": false, "retries": true})
		case r.Connect != nil:
			out.Encode(s.open(r.Connect))
		case r.Disconnect:
			s.close()
			out.Encode(map[string]any{"disconnected": true})
		case r.Op == "close":
			return
		case !contains(ops, r.Op):
			out.Encode(map[string]any{"id": r.ID, "ok": false, "error": "unsupported"})
		case s.client == nil:
			out.Encode(map[string]any{"id": r.ID, "ok": false, "error": "other", "detail": "not connected"})
		default:
			unit := 1
			if r.Unit != nil {
				unit = *r.Unit
			}
			s.setUnit(byte(unit))
			values, err := s.call(&r)
			if err != nil {
				out.Encode(failure(r.ID, err))
			} else {
				out.Encode(map[string]any{"id": r.ID, "ok": true, "values": values})
			}
		}
	}
}
