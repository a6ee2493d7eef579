// The npm package modbus-serial's ServerTCP as a library's own test server
// would run it (modbus-serial examples/server.js): a vector over arrays of
// 200 coils, discrete inputs, input and holding registers; an address past
// them throws { modbusErrorCode: 0x02 } (illegal data address), the
// package's documented way to refuse. Prints "listening PORT" when ready.
//
// usage: node modbus_serial_server.js PORT   (NODE_PATH: the build tree's node_modules)
"use strict";
const ModbusRTU = require("modbus-serial");

const ITEMS = 200;
const port = parseInt(process.argv[2], 10);
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

const server = new ModbusRTU.ServerTCP(vector, { host: "127.0.0.1", port: port, debug: false, unitID: 1 });
server.on("initialized", () => console.log("listening " + port));
server.on("socketError", (err) => console.error("socket error: " + err));
