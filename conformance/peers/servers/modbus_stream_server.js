// The npm package modbus-stream as a server: it parses requests and emits one
// event per function code, and a server is the handlers its user writes
// (its README's "Responses"). This is that glue, kept minimal: the data model
// and nothing else. It keeps arrays of 200 coils, discrete inputs, input and
// holding registers; a request whose address range runs past them gets
// IllegalDataAddress (02), any other is read or written and answered as the
// package builds the reply. The protocol is the package's: function codes it
// does not know, PDU lengths, quantity limits, byte counts, FC 05 values,
// framing; the glue checks none of them, so a deviation there is the
// package's, not the glue's. Prints "listening PORT" when ready.
//
// usage: node modbus_stream_server.js PORT            Modbus TCP on 127.0.0.1
//        node modbus_stream_server.js --rtu-tcp PORT  RTU frames over TCP (its TCP driver
//                                                     with its RTU transport)
//        (NODE_PATH: the build tree's peers/node_modules)
"use strict";
const modbus = require("modbus-stream");

const ITEMS = 200;
const bits = { coils: new Array(ITEMS).fill(0), discrete: new Array(ITEMS).fill(0) };
const words = { holding: new Array(ITEMS).fill(0), input: new Array(ITEMS).fill(0) };

function word(v) {
  const b = Buffer.alloc(2);
  b.writeUInt16BE(v, 0);
  return b;
}

// IllegalDataAddress when [address, address + quantity) is not all data, else null.
function refuse(address, quantity) {
  return address + quantity > ITEMS ? "IllegalDataAddress" : null;
}

function handlers(conn) {
  const readBits = (table) => (req, reply) => {
    const { address, quantity } = req.request;
    const e = refuse(address, quantity);
    return e ? reply(e) : reply(null, bits[table].slice(address, address + quantity));
  };
  const readWords = (table) => (req, reply) => {
    const { address, quantity } = req.request;
    const e = refuse(address, quantity);
    return e ? reply(e) : reply(null, words[table].slice(address, address + quantity).map(word));
  };
  conn.on("read-coils", readBits("coils"));
  conn.on("read-discrete-inputs", readBits("discrete"));
  conn.on("read-holding-registers", readWords("holding"));
  conn.on("read-input-registers", readWords("input"));
  conn.on("write-single-coil", (req, reply) => {
    const { address, value } = req.request;
    if (address >= ITEMS) return reply("IllegalDataAddress");
    bits.coils[address] = value ? 1 : 0;
    return reply(null, address, value);
  });
  conn.on("write-single-register", (req, reply) => {
    const { address, value } = req.request;
    if (address >= ITEMS) return reply("IllegalDataAddress");
    words.holding[address] = value.readUInt16BE(0);
    return reply(null, address, value);
  });
  conn.on("write-multiple-coils", (req, reply) => {
    const { address, quantity, values } = req.request;
    const e = refuse(address, quantity);
    if (e) return reply(e);
    for (let i = 0; i < quantity; i++) bits.coils[address + i] = values[i] ? 1 : 0;
    return reply(null, address, quantity);
  });
  conn.on("write-multiple-registers", (req, reply) => {
    const { address, quantity, values } = req.request;
    const e = refuse(address, quantity);
    if (e) return reply(e);
    values.slice(0, quantity).forEach((v, i) => { words.holding[address + i] = v.readUInt16BE(0); });
    return reply(null, address, quantity);
  });
  conn.on("mask-write-register", (req, reply) => {
    const { address, andmask, ormask } = req.request;
    if (address >= ITEMS) return reply("IllegalDataAddress");
    const and = andmask.readUInt16BE(0), or = ormask.readUInt16BE(0);
    words.holding[address] = (words.holding[address] & and) | (or & ~and & 0xFFFF);
    return reply(null, address, andmask, ormask);
  });
  conn.on("read-write-multiple-registers", (req, reply) => {
    const r = req.request;
    const e = refuse(r.read_address, r.read_quantity) || refuse(r.write_address, r.values.length);
    if (e) return reply(e);
    r.values.forEach((v, i) => { words.holding[r.write_address + i] = v.readUInt16BE(0); });
    return reply(null, words.holding.slice(r.read_address, r.read_address + r.read_quantity).map(word));
  });
  conn.on("error", (e) => console.error("modbus-stream server: " + e));
}

const rtu = process.argv[2] === "--rtu-tcp";
const port = parseInt(process.argv[rtu ? 3 : 2], 10);
const options = { debug: null };
const server = rtu ? modbus.drivers.tcp.server(options).attach(modbus.transports.serial.prepare(options), handlers)
                   : modbus.tcp.server(options, handlers);
server.listen(port, "127.0.0.1", () => console.log("listening " + port));
