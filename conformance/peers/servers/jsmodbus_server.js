// The npm package jsmodbus's server as a library's own test server would run
// it (its README's "Server example"): a ModbusTCPServer on a net.Server, or a
// ModbusRTUServer on a serial port, over buffers of 200 coils, discrete
// inputs, input and holding registers; the package answers past them itself.
// Prints "listening PORT" (or "listening DEVICE") when ready.
//
// usage: node jsmodbus_server.js PORT                 Modbus TCP on 127.0.0.1
//        node jsmodbus_server.js --rtu DEVICE BAUD    RTU on a serial line (a pty)
//        (NODE_PATH: the build tree's peers/node_modules)
"use strict";
const net = require("net");
const Modbus = require("jsmodbus");

const ITEMS = 200;
const tables = {
  coils: Buffer.alloc(ITEMS / 8),
  discrete: Buffer.alloc(ITEMS / 8),
  holding: Buffer.alloc(ITEMS * 2),
  input: Buffer.alloc(ITEMS * 2),
};

if (process.argv[2] === "--rtu") {
  const { SerialPort } = require("serialport");  // the one in the same lock file
  const device = process.argv[3];
  const port = new SerialPort({ path: device, baudRate: parseInt(process.argv[4] || "19200", 10), autoOpen: false });
  port.open((err) => {
    if (err) {
      console.error("cannot open " + device + ": " + err.message);
      process.exit(2);
    }
    new Modbus.server.RTU(port, tables);
    console.log("listening " + device);
  });
} else {
  const port = parseInt(process.argv[2], 10);
  const server = new net.Server();
  new Modbus.server.TCP(server, tables);
  server.listen(port, "127.0.0.1", () => console.log("listening " + port));
}
