// The protocol client: one WebSocket, text frames `cmd args` out, one JSON
// object back per request.
//
// The server never pushes and answers every request in order, so an answer
// belongs to the oldest request still waiting: requests and answers are
// paired first in, first out.

/** What a `ret` code means (the contract's error table). */
const RET_WORDS = new Map([
  [0, 'ok'],
  [-1, 'failed or refused'],
  [-2, 'invalid arguments or unsupported'],
  [-3, 'system or autopilot failure'],
  [-100, 'unhandled exception'],
]);

/** The message of a session that must log in first. */
export const LOGIN_FIRST = 'Login first!';

/** `ret` in words, e.g. `-2` → "invalid arguments or unsupported". */
export function retWords(ret) {
  return RET_WORDS.get(ret) ?? `unknown code ${ret}`;
}

/** The command name of a request line. */
export function commandName(text) {
  return text.trim().split(/\s+/, 1)[0] ?? '';
}

/**
 * The WebSocket URL a page served from `location` talks to: its own origin
 * (`wss:` under https), unless the page's query names another (`?ws=`);
 * lluavd's Content-Security-Policy confines that to the page's own origin.
 */
export function defaultUrl(location) {
  const override = new URLSearchParams(location.search).get('ws');
  if (override) return override;
  const scheme = location.protocol === 'https:' ? 'wss:' : 'ws:';
  return `${scheme}//${location.host}/`;
}

/** One request and its answer. */
export class Exchange {
  constructor(request, answer, ms) {
    /** The request line as sent. */
    this.request = request;
    /** The parsed JSON answer. */
    this.answer = answer;
    /** Milliseconds from sending to the answer. */
    this.ms = ms;
  }

  /** The answer's `ret` (NaN when it has none). */
  get ret() {
    return Number.isInteger(this.answer?.ret) ? this.answer.ret : NaN;
  }

  /** Whether the command succeeded. */
  get ok() {
    return this.ret === 0;
  }

  /** The answer's `msg`, or ''. */
  get msg() {
    return typeof this.answer?.msg === 'string' ? this.answer.msg : '';
  }

  /** Whether the server asks this session to log in. */
  get needsLogin() {
    return this.ret === -1 && this.msg === LOGIN_FIRST;
  }
}

/**
 * A connection to lluavd. Events: `open`; `close` with
 * `detail: {code, reason}`; `stray` with `detail: text` for an answer no
 * request was waiting for (which the protocol never produces).
 */
export class Client extends EventTarget {
  #ws = null;
  #waiting = [];

  constructor(url) {
    super();
    /** Where this client connects. */
    this.url = url;
  }

  /** Whether the socket is open. */
  get isOpen() {
    return this.#ws?.readyState === WebSocket.OPEN;
  }

  /** Requests sent and not yet answered. */
  get inFlight() {
    return this.#waiting.length;
  }

  /** Opens the socket; resolves once it is open, rejects if it closes first. */
  connect() {
    return new Promise((resolve, reject) => {
      let ws;
      try {
        ws = new WebSocket(this.url);
      } catch (e) {
        // A bad URL, or one the page's Content-Security-Policy forbids.
        reject(e);
        this.dispatchEvent(new CustomEvent('close', { detail: { code: 1006, reason: e.message } }));
        return;
      }
      this.#ws = ws;
      let ended = false;
      const end = (code, reason) => {
        if (ended) return;
        ended = true;
        reject(new Error(`cannot connect to ${this.url} (${reason})`));
        if (this.#ws === ws) this.#ws = null;
        this.#failAll(new Error(`connection closed (${code} ${reason})`));
        this.dispatchEvent(new CustomEvent('close', { detail: { code, reason } }));
      };
      ws.addEventListener('open', () => {
        resolve();
        this.dispatchEvent(new Event('open'));
      });
      ws.addEventListener('message', (event) => this.#answer(event.data));
      ws.addEventListener('close', (event) => end(event.code, event.reason || closeWords(event.code)));
      // A connection the page's policy blocks fails with an error and no
      // close event (Chromium): it is closed all the same.
      ws.addEventListener('error', () => setTimeout(() => {
        if (ws.readyState === WebSocket.CLOSED) end(1006, 'refused');
      }, 0));
    });
  }

  /** Closes the socket; waiting requests fail. */
  close() {
    this.#ws?.close(1000, 'bye');
  }

  /**
   * Sends one request line; resolves with its {@link Exchange}, rejects
   * when the connection is not open or closes before the answer.
   */
  request(text) {
    if (!this.isOpen) return Promise.reject(new Error('not connected'));
    return new Promise((resolve, reject) => {
      this.#waiting.push({ text, resolve, reject, sent: performance.now() });
      this.#ws.send(text);
    });
  }

  #answer(data) {
    const entry = this.#waiting.shift();
    if (!entry) {
      this.dispatchEvent(new CustomEvent('stray', { detail: String(data) }));
      return;
    }
    const ms = performance.now() - entry.sent;
    let answer;
    try {
      answer = JSON.parse(data);
    } catch {
      entry.reject(new Error(`answer is not JSON: ${String(data).slice(0, 200)}`));
      return;
    }
    entry.resolve(new Exchange(entry.text, answer, ms));
  }

  #failAll(error) {
    const waiting = this.#waiting;
    this.#waiting = [];
    for (const entry of waiting) entry.reject(error);
  }
}

/** Close codes the server uses, in words. */
function closeWords(code) {
  switch (code) {
    case 1000: return 'closed';
    case 1001: return 'server going away';
    case 1006: return 'no connection';
    case 1008: return 'policy: too many wrong passwords';
    case 1009: return 'message too big';
    case 1011: return 'server error';
    default: return `code ${code}`;
  }
}
