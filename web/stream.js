// The page's one live connection: an EventSource on /api/stream (scene, rollout, runs, metrics, log).
// When it breaks (the server stopped, a network cut, or three heartbeats missed) the page says so and
// reconnects with backoff; the server's `hello` tells whether it is the same server or a new one.
export class StudioStream {
  // url(query) -> the stream's URL; handlers: event name -> fn(data); onUp(hello, afterOutage); onDown(attempt).
  constructor({ url, handlers, onUp, onDown }) {
    Object.assign(this, { url, handlers, onUp, onDown });
    this.source = null;
    this.query = {};
    this.down = false;
    this.attempt = 0;
    this.heartbeatS = 5;
    this.watchdog = null;
    this.retryTimer = null;
  }

  // (Re)connect with another subscription, e.g. when another run is selected.
  open(query = {}) {
    this.query = query;
    if (!this.down) this._connect();
  }

  _connect() {
    this._close();
    const q = new URLSearchParams();
    for (const [k, v] of Object.entries(this.query)) if (v !== null && v !== undefined) q.set(k, String(v));
    const source = new EventSource(this.url(q.toString() ? `/api/stream?${q}` : "/api/stream"));
    this.source = source;
    source.addEventListener("hello", (ev) => {
      const hello = JSON.parse(ev.data);
      this.heartbeatS = hello.heartbeat_s || this.heartbeatS;
      const afterOutage = this.down;
      this.down = false;
      this.attempt = 0;
      this._alive();
      this.onUp(hello, afterOutage);
    });
    for (const [name, fn] of Object.entries(this.handlers)) {
      source.addEventListener(name, (ev) => {
        if (source !== this.source) return;  // a late event of a connection already replaced
        this._alive();
        fn(JSON.parse(ev.data));
      });
    }
    source.addEventListener("heartbeat", () => this._alive());
    // EventSource would retry by itself, silently; the page wants to say that the server is gone.
    source.onerror = () => { if (source === this.source) this._lost(); };
  }

  _close() {
    clearTimeout(this.watchdog);
    if (this.source) this.source.close();
    this.source = null;
  }

  // Any event proves the server alive; silence for three heartbeats means it is not (a half-open TCP
  // connection, e.g. a suspended laptop or a proxy that dropped it, gives no error event).
  _alive() {
    clearTimeout(this.watchdog);
    this.watchdog = setTimeout(() => this._lost(), 3 * this.heartbeatS * 1000);
  }

  _lost() {
    this._close();
    this.down = true;
    this.attempt += 1;
    this.onDown(this.attempt);
    const delay = Math.min(500 * 2 ** (this.attempt - 1), 5000);  // 0.5, 1, 2, 4, 5, 5 … s
    clearTimeout(this.retryTimer);
    this.retryTimer = setTimeout(() => this._connect(), delay);
  }
}
