#!/usr/bin/env node
// The jsmodbus adapter of `mbconform client` (protocol 1,
// conformance/client/README.md): the npm package's ModbusTCPClient on a
// net.Socket and ModbusRTUClient on a serialport, as its README shows. The
// package has no FC 22 or FC 23 call and no raw PDU, so those ops are not
// listed; it has no RTU over TCP. Its client takes the unit id in its
// constructor, and a TCP client must exist before its socket connects (it
// goes online on the socket's 'connect' event): so on TCP the adapter opens
// the connection at the first request, with a client for that request's unit,
// and opens a new one if a later request names another unit. On RTU it makes
// one client per unit on the open port. One JSON object a line on stdin, one
// answer a line on stdout; logs to stderr.
//
//   node jsmodbus_adapter.js            (NODE_PATH: the build tree's peers/node_modules)
"use strict";

const net = require("net");
const readline = require("readline");
const Modbus = require("jsmodbus");
const version = require("jsmodbus/package.json").version;

const PROTOCOL = 1;
const OPS = ["read_coils", "read_discrete_inputs", "read_holding_registers", "read_input_registers",
    "write_single_coil", "write_single_register", "write_multiple_coils", "write_multiple_registers",
    "read_device_identification"];

// The connection: its socket or serial port, how clients are made on it, and
// the clients made so far (by unit); on TCP, where to connect.
let conn = null;

function send(obj) {
    process.stdout.write(JSON.stringify(obj) + "\n");
}

async function clientFor(unit) {
    if (conn.tcp && !conn.clients.has(unit)) {
        const c = conn.tcp;
        await close();
        conn = await openTcp(c, unit);
    }
    if (!conn.clients.has(unit)) conn.clients.set(unit, conn.make(unit));
    return conn.clients.get(unit);
}

function call(c, r) {
    const a = r.address || 0;
    switch (r.op) {
        case "read_coils": return c.readCoils(a, r.count);
        case "read_discrete_inputs": return c.readDiscreteInputs(a, r.count);
        case "read_holding_registers": return c.readHoldingRegisters(a, r.count);
        case "read_input_registers": return c.readInputRegisters(a, r.count);
        case "write_single_coil": return c.writeSingleCoil(a, Boolean(r.value));
        case "write_single_register": return c.writeSingleRegister(a, r.value);
        case "write_multiple_coils": return c.writeMultipleCoils(a, r.values.map(Boolean));
        case "write_multiple_registers": return c.writeMultipleRegisters(a, r.values);
        case "read_device_identification": return c.readDeviceIdentification(1, r.object_id || 0);
    }
    return null;
}

function valuesOf(r, body) {
    if (r.op === "read_coils" || r.op === "read_discrete_inputs") return Array.from(body.valuesAsArray).slice(0, r.count).map(Boolean);
    if (r.op === "read_holding_registers" || r.op === "read_input_registers") return Array.from(body.valuesAsArray);
    if (r.op === "read_device_identification") {
        const objects = {};
        for (const o of body.objects) objects["0x" + o.id.toString(16).toUpperCase().padStart(2, "0")] = o.value.toString("latin1");
        return {objects};
    }
    return [];
}

// The library's error, in the protocol's words: a UserRequestError's `err`,
// or an Error from a request body's constructor (InvalidQuantity, ...), which
// the package throws before anything is sent.
function failure(id, e) {
    const msg = String(e && e.message || e);
    switch (e && e.err) {
        case "ModbusException": return {id, ok: false, error: "exception", code: e.response.body.code};
        case "Timeout": return {id, ok: false, error: "timeout", detail: msg};
        case "OutOfSync": case "Protocol": case "crcMismatch": return {id, ok: false, error: "invalid_reply", detail: e.err + ": " + msg};
        case undefined: if (/^Invalid/.test(msg)) return {id, ok: false, error: "refused", detail: msg};
    }
    return {id, ok: false, error: "other", detail: (e && e.err ? e.err + ": " : "") + msg};
}

async function request(r) {
    const id = r.id;
    if (!OPS.includes(r.op)) return {id, ok: false, error: "unsupported"};
    try {
        const res = await call(await clientFor(r.unit === undefined ? 1 : r.unit), r);
        return {id, ok: true, values: valuesOf(r, res.response.body)};
    } catch (e) {
        return failure(id, e);
    }
}

async function close() {
    if (!conn) return;
    const c = conn;
    conn = null;
    await new Promise((resolve) => {
        if (!c.socket || c.socket.destroyed || c.socket.isOpen === false) return resolve();
        c.socket.once("close", () => resolve());
        if (c.socket.destroy && !c.socket.path) c.socket.destroy();
        else c.socket.close(() => resolve());
    });
}

function openTcp(c, unit) {
    return new Promise((resolve, reject) => {
        const socket = new net.Socket();
        const clients = new Map([[unit, new Modbus.client.TCP(socket, unit, c.timeout_ms || 500)]]);
        socket.once("error", reject);
        socket.connect({host: c.host, port: c.port}, () => {
            socket.removeListener("error", reject);
            socket.on("error", (e) => process.stderr.write("jsmodbus adapter: socket: " + e + "\n"));
            resolve({socket, clients, tcp: c});
        });
    });
}

function openRtu(c, timeout) {
    // serialport is the one modbus-serial brings (the same lock file); jsmodbus
    // takes any opened port.
    const {SerialPort} = require("serialport");
    return new Promise((resolve, reject) => {
        const socket = new SerialPort({path: c.device, baudRate: c.baud || 9600, dataBits: c.data || 8, stopBits: c.stop || 1,
            parity: {N: "none", E: "even", O: "odd"}[c.parity || "N"], autoOpen: false});
        socket.open((e) => e ? reject(e) : resolve({socket, clients: new Map(), make: (unit) => new Modbus.client.RTU(socket, unit, timeout)}));
    });
}

async function connect(c) {
    await close();
    const timeout = c.timeout_ms || 500;
    try {
        if (c.transport === "tcp") conn = {tcp: c, clients: new Map()};  // opened at the first request
        else if (c.transport === "rtu") conn = await openRtu(c, timeout);
        else return {ready: false, detail: "jsmodbus has no transport " + c.transport};
    } catch (e) {
        return {ready: false, detail: String(e && e.message || e)};
    }
    // jsmodbus sends each request once: there are no retries to turn off.
    return {ready: true};
}

async function main() {
    const rl = readline.createInterface({input: process.stdin, terminal: false});
    for await (const line of rl) {
        let msg;
        try {
            msg = JSON.parse(line);
        } catch (e) {
            process.stderr.write("jsmodbus adapter: not JSON: " + line + "\n");
            continue;
        }
        if (msg.hello) send({protocol: PROTOCOL, library: "jsmodbus", version, ops: OPS, raw: false, retries: true});
        else if (msg.connect) send(await connect(msg.connect));
        else if (msg.disconnect) {
            await close();
            send({disconnected: true});
        } else if (msg.op === "close") break;
        else send(await request(msg));
    }
    await close();
    process.exit(0);
}

main();
