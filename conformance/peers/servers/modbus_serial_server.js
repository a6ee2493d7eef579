// The npm package modbus-serial's ServerTCP as a library's own test server
// would run it (modbus-serial examples/server.js): a vector over arrays of
// 200 coils, discrete inputs, input and holding registers; an address past
// them throws { modbusErrorCode: 0x02 } (illegal data address), the
// package's documented way to refuse. Prints "listening PORT" when ready.
// With --rtu it serves the same vector with ServerSerial (RTU on a serial
// line: a pty, 8N1 at BAUD, unit 1; the package's serialport), printing
// "listening DEVICE" once the port is open.
//
// usage: node modbus_serial_server.js PORT               (NODE_PATH: the build tree's node_modules)
//        node modbus_serial_server.js --rtu DEVICE BAUD
"use strict";
const ModbusRTU = require("modbus-serial");

const ITEMS = 200;
const coils = new Array(ITEMS).fill(false);
const discrete = new Array(ITEMS).fill(false);
const input = new Array(ITEMS).fill(0);
const holding = new Array(ITEMS).fill(0);

function at(table, addr) {
  if (addr < 0 || addr >= ITEMS) throw { modbusErrorCode: 0x02, msg: "Illegal data address " + addr };
  return table[addr];
}

const vector = {
  getCoil: (addr) => at(coils, addr),
  getDiscreteInput: (addr) => at(discrete, addr),
  getInputRegister: (addr) => at(input, addr),
  getHoldingRegister: (addr) => at(holding, addr),
  setCoil: (addr, value) => { at(coils, addr); coils[addr] = value; },
  setRegister: (addr, value) => { at(holding, addr); holding[addr] = value; },
};

if (process.argv[2] === "--rtu") {
  const device = process.argv[3];
  const server = new ModbusRTU.ServerSerial(vector, { port: device, baudrate: parseInt(process.argv[4], 10), unitID: 1 });
  server.getPort().on("open", () => console.log("listening " + device));
  server.on("socketError", (err) => {
    console.error("serial error: " + err);
    process.exit(2);  // the port did not open: no "listening", the matrix says so
  });
} else {
  const port = parseInt(process.argv[2], 10);
  const server = new ModbusRTU.ServerTCP(vector, { host: "127.0.0.1", port: port, debug: false, unitID: 1 });
  server.on("initialized", () => console.log("listening " + port));
  server.on("socketError", (err) => console.error("socket error: " + err));
}
