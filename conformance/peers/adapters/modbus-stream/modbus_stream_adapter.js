#!/usr/bin/env node
// The modbus-stream adapter of `mbconform client` (protocol 1,
// conformance/client/README.md): the npm package's connection API
// (`modbus.tcp.connect`, and for RTU over TCP its TCP driver with its RTU
// transport, `drivers.tcp.connect(...).attach(transports.serial.prepare(...))`,
// which the package exports for combining). RTU on a serial line needs its
// serialport 6, whose native build fails here (conformance/peers installs
// without optional packages): "rtu" answers ready: false. Values go as the
// package takes them (registers as 2-byte Buffers, coils as 0/1), and the
// unit in each request's `extra`. The response time-out is its `retry`
// option, with `retries` 0. One JSON object a line on stdin, one answer a
// line on stdout; its debug trace goes to stderr.
//
//   node modbus_stream_adapter.js            (NODE_PATH: the build tree's peers/node_modules)
"use strict";

const readline = require("readline");
const modbus = require("modbus-stream");
const version = require("modbus-stream/package.json").version;

const PROTOCOL = 1;
const OPS = ["read_coils", "read_discrete_inputs", "read_holding_registers", "read_input_registers",
    "write_single_coil", "write_single_register", "write_multiple_coils", "write_multiple_registers",
    "mask_write_register", "read_write_multiple_registers", "read_device_identification"];
// modbus-pdu's names of the basic device identification objects.
const OBJECT_IDS = {VendorName: 0, ProductCode: 1, MajorMinorRevision: 2};

let conn = null;  // {stream, rtu}

function send(obj) {
    process.stdout.write(JSON.stringify(obj) + "\n");
}

function word(v) {
    const b = Buffer.alloc(2);
    b.writeUInt16BE(v, 0);
    return b;
}

// The package's call for one op, with its callback.
function call(s, r, extra, next) {
    const a = r.address || 0;
    switch (r.op) {
        case "read_coils": return s.readCoils({address: a, quantity: r.count, extra}, next);
        case "read_discrete_inputs": return s.readDiscreteInputs({address: a, quantity: r.count, extra}, next);
        case "read_holding_registers": return s.readHoldingRegisters({address: a, quantity: r.count, extra}, next);
        case "read_input_registers": return s.readInputRegisters({address: a, quantity: r.count, extra}, next);
        case "write_single_coil": return s.writeSingleCoil({address: a, value: r.value ? 1 : 0, extra}, next);
        case "write_single_register": return s.writeSingleRegister({address: a, value: word(r.value), extra}, next);
        case "write_multiple_coils": return s.writeMultipleCoils({address: a, values: r.values.map((v) => v ? 1 : 0), extra}, next);
        case "write_multiple_registers": return s.writeMultipleRegisters({address: a, values: r.values.map(word), extra}, next);
        case "mask_write_register": return s.maskWriteRegister({address: a, andmask: r.and_mask, ormask: r.or_mask, extra}, next);
        case "read_write_multiple_registers":
            return s.readWriteMultipleRegisters({read_address: r.read_address, read_quantity: r.read_count,
                write_address: r.write_address, values: r.values.map(word), extra}, next);
        case "read_device_identification": return s.readDeviceIdentification({type: "BasicDeviceIdentification", id: r.object_id || 0, extra}, next);
    }
    return next(new Error("unsupported op " + r.op));
}

function valuesOf(r, res) {
    switch (r.op) {
        case "read_coils": case "read_discrete_inputs": return res.data.slice(0, r.count).map(Boolean);
        case "read_holding_registers": case "read_input_registers": return res.data.map((b) => b.readUInt16BE(0));
        case "read_write_multiple_registers": return res.values.map((b) => b.readUInt16BE(0));
        case "read_device_identification": {
            const objects = {};
            for (const o of res.objects) {
                const id = typeof o.id === "number" ? o.id : OBJECT_IDS[o.id];
                objects["0x" + id.toString(16).toUpperCase().padStart(2, "0")] = o.value.toString("latin1");
            }
            return {objects};
        }
    }
    return [];
}

// The package's error, in the protocol's words. An exception reply is an
// Error whose message is modbus-pdu's name of the code; its own time-out is
// the Error of GatewayTargetDeviceFailedToRespond with `code` 0x0B set.
function failure(id, e) {
    const msg = String(e && e.message || e);
    if (e && e.code === modbus.pdu.Exception.GatewayTargetDeviceFailedToRespond && msg === "GatewayTargetDeviceFailedToRespond")
        return {id, ok: false, error: "timeout", detail: "no reply within retry (" + msg + ")"};
    if (typeof modbus.pdu.Exception[msg] === "number") return {id, ok: false, error: "exception", code: modbus.pdu.Exception[msg]};
    if (/out of bounds|overflow|range/i.test(msg)) return {id, ok: false, error: "refused", detail: msg};
    return {id, ok: false, error: "other", detail: msg};
}

function request(r) {
    const id = r.id;
    if (!OPS.includes(r.op)) return Promise.resolve({id, ok: false, error: "unsupported"});
    const unit = r.unit === undefined ? 1 : r.unit;
    const extra = conn.rtu ? {slaveId: unit} : {unitId: unit};
    return new Promise((resolve) => {
        try {
            call(conn.stream, r, extra, (err, res) => {
                if (err) resolve(failure(id, err));
                else {
                    try {
                        resolve({id, ok: true, values: valuesOf(r, res.response)});
                    } catch (e) {
                        resolve({id, ok: false, error: "invalid_reply", detail: "the package's response: " + e});
                    }
                }
            });
        } catch (e) {  // modbus-pdu throws while building a request it will not send
            resolve(failure(id, e));
        }
    });
}

async function close() {
    if (!conn) return;
    const c = conn;
    conn = null;
    await new Promise((resolve) => {
        try {
            c.stream.close(() => resolve());
        } catch (e) {
            resolve();
        }
        setTimeout(resolve, 200);  // a socket already gone does not call back
    });
}

function connect(c) {
    const options = {retry: c.timeout_ms || 500, retries: 0, debug: "modbus-stream", connectTimeout: 2000};
    return new Promise((resolve) => {
        const done = (err, stream) => {
            if (err) return resolve({ready: false, detail: String(err.message || err)});
            stream.on("error", (e) => process.stderr.write("modbus-stream adapter: " + e + "\n"));
            conn = {stream, rtu: c.transport === "rtu-tcp"};
            resolve({ready: true});
        };
        if (c.transport === "tcp") modbus.tcp.connect(c.port, c.host, options, done);
        else if (c.transport === "rtu-tcp") {
            modbus.drivers.tcp.connect(c.port, c.host, options).attach(modbus.transports.serial.prepare(options), done);
        } else resolve({ready: false, detail: "modbus-stream's serial driver needs serialport 6, whose native build fails here"});
    });
}

async function main() {
    const rl = readline.createInterface({input: process.stdin, terminal: false});
    for await (const line of rl) {
        let msg;
        try {
            msg = JSON.parse(line);
        } catch (e) {
            process.stderr.write("modbus-stream adapter: not JSON: " + line + "\n");
            continue;
        }
        if (msg.hello) send({protocol: PROTOCOL, library: "modbus-stream", version, ops: OPS, raw: false, retries: true});
        else if (msg.connect) {
            await close();
            send(await connect(msg.connect));
        } else if (msg.disconnect) {
            await close();
            send({disconnected: true});
        } else if (msg.op === "close") break;
        else send(await request(msg));
    }
    await close();
    process.exit(0);
}

main();
