// The protocol client against a scripted WebSocket: node --test.
import { test } from 'node:test';
import assert from 'node:assert/strict';

/** A WebSocket the test plays the server of. */
class FakeSocket extends EventTarget {
  static OPEN = 1;
  static CLOSED = 3;
  static last = null;
  constructor(url) {
    super();
    this.url = url;
    this.readyState = 0;
    this.sent = [];
    FakeSocket.last = this;
  }
  send(text) { this.sent.push(text); }
  close(code = 1000, reason = '') { this.serverClose(code, reason); }
  serverOpen() { this.readyState = 1; this.dispatchEvent(new Event('open')); }
  serverSend(data) { const e = new Event('message'); e.data = data; this.dispatchEvent(e); }
  serverClose(code, reason = '') {
    this.readyState = 3;
    const e = new Event('close'); e.code = code; e.reason = reason;
    this.dispatchEvent(e);
  }
}
globalThis.WebSocket = FakeSocket;

const { Client, defaultUrl, retWords, commandName } = await import('../../../host/console/protocol.js');

async function connected() {
  const client = new Client('ws://vehicle:53001/');
  const opening = client.connect();
  FakeSocket.last.serverOpen();
  await opening;
  return { client, socket: FakeSocket.last };
}

test('answers pair with requests first in, first out', async () => {
  const { client, socket } = await connected();
  const a = client.request('state');
  const b = client.request('takeoff');
  const c = client.request('bogus');
  assert.deepEqual(socket.sent, ['state', 'takeoff', 'bogus']);
  assert.equal(client.inFlight, 3);
  socket.serverSend('{"ret":0,"cmd":2,"state":{}}');
  socket.serverSend('{"ret":-1,"cmd":18,"msg":"Not allow when vehicle is ARMED!"}');
  socket.serverSend('{"ret":-2,"cmd":0,"msg":"Unsupported command: bogus"}');
  const [ea, eb, ec] = await Promise.all([a, b, c]);
  assert.equal(ea.request, 'state');
  assert.ok(ea.ok);
  assert.equal(eb.request, 'takeoff');
  assert.equal(eb.ret, -1);
  assert.equal(eb.msg, 'Not allow when vehicle is ARMED!');
  assert.equal(ec.ret, -2);
  assert.equal(client.inFlight, 0);
});

test('"Login first!" is recognised', async () => {
  const { client, socket } = await connected();
  const a = client.request('state');
  socket.serverSend('{"ret":-1,"cmd":2,"ts":1,"msg":"Login first!"}');
  assert.ok((await a).needsLogin);
});

test('a close fails every waiting request and says why', async () => {
  const { client, socket } = await connected();
  const closes = [];
  client.addEventListener('close', (e) => closes.push(e.detail));
  const a = client.request('state');
  const b = client.request('help');
  socket.serverClose(1008, '');
  await assert.rejects(a, /connection closed \(1008/);
  await assert.rejects(b, /connection closed/);
  assert.deepEqual(closes, [{ code: 1008, reason: 'policy: too many wrong passwords' }]);
  await assert.rejects(client.request('state'), /not connected/);
});

test('a connection refused with an error and no close event counts as closed', async () => {
  const client = new Client('ws://elsewhere:1/');
  const closes = [];
  client.addEventListener('close', (e) => closes.push(e.detail));
  const opening = client.connect();
  const socket = FakeSocket.last;
  socket.readyState = 3;
  socket.dispatchEvent(new Event('error'));
  await assert.rejects(opening, /cannot connect to ws:\/\/elsewhere:1\/ \(refused\)/);
  assert.deepEqual(closes, [{ code: 1006, reason: 'refused' }]);
});

test('an error followed by a close reports the close once, with its code', async () => {
  const client = new Client('ws://vehicle:1/');
  const closes = [];
  client.addEventListener('close', (e) => closes.push(e.detail));
  const opening = client.connect();
  const socket = FakeSocket.last;
  socket.readyState = 3;
  socket.dispatchEvent(new Event('error'));
  socket.serverClose(1006);
  await assert.rejects(opening);
  await new Promise((r) => setTimeout(r, 5));
  assert.deepEqual(closes, [{ code: 1006, reason: 'no connection' }]);
});

test('an answer that is not JSON fails its request only', async () => {
  const { client, socket } = await connected();
  const a = client.request('state');
  const b = client.request('ver');
  socket.serverSend('not json');
  socket.serverSend('{"ret":0,"cmd":5}');
  await assert.rejects(a, /not JSON/);
  assert.ok((await b).ok);
});

test('an answer nobody asked for is reported, not paired', async () => {
  const { client, socket } = await connected();
  const stray = [];
  client.addEventListener('stray', (e) => stray.push(e.detail));
  socket.serverSend('{"ret":0}');
  assert.deepEqual(stray, ['{"ret":0}']);
});

test('the page talks to its own origin, over wss under https', () => {
  assert.equal(defaultUrl({ protocol: 'http:', host: '127.0.0.1:53001', search: '' }), 'ws://127.0.0.1:53001/');
  assert.equal(defaultUrl({ protocol: 'https:', host: 'drone.local:53001', search: '' }), 'wss://drone.local:53001/');
  assert.equal(defaultUrl({ protocol: 'http:', host: 'a:1', search: '?ws=ws://b:2/' }), 'ws://b:2/');
});

test('codes in words', () => {
  assert.equal(retWords(0), 'ok');
  assert.equal(retWords(-1), 'failed or refused');
  assert.equal(retWords(-2), 'invalid arguments or unsupported');
  assert.equal(retWords(-3), 'system or autopilot failure');
  assert.equal(retWords(-100), 'unhandled exception');
  assert.equal(retWords(-7), 'unknown code -7');
  assert.equal(commandName('  set_sp_ned 1:2:3:4'), 'set_sp_ned');
});
