#!/usr/bin/env node
// The modbus-serial adapter of `mbconform client` (protocol 1,
// conformance/client/README.md): the npm package's client, through its
// promise API, as its README shows. The package has no FC 22 or FC 23 call,
// so those ops are not listed. One JSON object a line on stdin, one answer a
// line on stdout; logs to stderr.
//
//   node modbus_serial_adapter.js            (NODE_PATH: the build tree's peers/node_modules)
"use strict";

const readline = require("readline");
const ModbusRTU = require("modbus-serial");
const version = require("modbus-serial/package.json").version;

const PROTOCOL = 1;
const OPS = ["read_coils", "read_discrete_inputs", "read_holding_registers", "read_input_registers",
    "write_single_coil", "write_single_register", "write_multiple_coils", "write_multiple_registers",
    "read_device_identification"];

let client = null;

function send(obj) {
    process.stdout.write(JSON.stringify(obj) + "\n");
}

function call(c, op, r) {
    const a = r.address || 0;
    switch (op) {
        case "read_coils": return c.readCoils(a, r.count);
        case "read_discrete_inputs": return c.readDiscreteInputs(a, r.count);
        case "read_holding_registers": return c.readHoldingRegisters(a, r.count);
        case "read_input_registers": return c.readInputRegisters(a, r.count);
        case "write_single_coil": return c.writeCoil(a, Boolean(r.value));
        case "write_single_register": return c.writeRegister(a, r.value);
        case "write_multiple_coils": return c.writeCoils(a, r.values.map(Boolean));
        case "write_multiple_registers": return c.writeRegisters(a, r.values);
        case "read_device_identification": return c.readDeviceIdentification(1, r.object_id || 0);
    }
    return null;
}

function valuesOf(op, res, r) {
    if (op === "read_coils" || op === "read_discrete_inputs") return res.data.slice(0, r.count).map(Boolean);
    if (op === "read_holding_registers" || op === "read_input_registers") return Array.from(res.data);
    if (op === "read_device_identification") {
        const objects = {};
        for (const [k, v] of Object.entries(res.data)) objects["0x" + Number(k).toString(16).toUpperCase().padStart(2, "0")] = v;
        return {objects};
    }
    return [];
}

// The library's error, in the protocol's words.
function failure(id, e) {
    const msg = String(e && e.message || e);
    if (e && e.modbusCode !== undefined) return {id, ok: false, error: "exception", code: e.modbusCode};
    if (e && (e.errno === "ETIMEDOUT" || e.name === "TransactionTimedOutError")) return {id, ok: false, error: "timeout", detail: msg};
    if (/CRC error|length error|Unexpected data|Invalid|expected/i.test(msg)) return {id, ok: false, error: "invalid_reply", detail: msg};
    if (e instanceof RangeError || e instanceof TypeError) return {id, ok: false, error: "refused", detail: msg};
    return {id, ok: false, error: "other", detail: msg};
}

async function request(r) {
    const id = r.id;
    if (!OPS.includes(r.op)) return {id, ok: false, error: "unsupported"};
    try {
        client.setID(r.unit === undefined ? 1 : r.unit);
        const res = await call(client, r.op, r);
        return {id, ok: true, values: valuesOf(r.op, res, r)};
    } catch (e) {
        return failure(id, e);
    }
}

async function close() {
    if (!client) return;
    const c = client;
    client = null;
    await new Promise((resolve) => { try { c.close(resolve); } catch (e) { resolve(); } });
}

async function connect(c) {
    await close();
    client = new ModbusRTU();
    try {
        if (c.transport === "tcp") await client.connectTCP(c.host, {port: c.port});
        // RTU frames over TCP: the package's TelnetPort (connectTcpRTUBuffered,
        // despite its name, sends MBAP frames).
        else if (c.transport === "rtu-tcp") await client.connectTelnet(c.host, {port: c.port});
        else if (c.transport === "rtu") {
            await client.connectRTUBuffered(c.device, {baudRate: c.baud || 9600, parity: {N: "none", E: "even", O: "odd"}[c.parity || "N"],
                dataBits: c.data || 8, stopBits: c.stop || 1});
        } else return {ready: false, detail: "no transport " + c.transport};
    } catch (e) {
        return {ready: false, detail: String(e && e.message || e)};
    }
    // modbus-serial sends each request once: there are no retries to turn off.
    client.setTimeout(c.timeout_ms || 500);
    return {ready: true};
}

async function main() {
    const rl = readline.createInterface({input: process.stdin, terminal: false});
    for await (const line of rl) {
        let msg;
        try {
            msg = JSON.parse(line);
        } catch (e) {
            process.stderr.write("modbus-serial adapter: not JSON: " + line + "\n");
            continue;
        }
        if (msg.hello) send({protocol: PROTOCOL, library: "modbus-serial", version, ops: OPS, raw: false, retries: true});
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
