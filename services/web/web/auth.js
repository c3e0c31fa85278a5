// The web console's authentication, the page's side (docs/web.md, "Authentication"): the
// password never leaves the page, the session key never leaves this tab's memory.
// WebCrypto (PBKDF2, HMAC-SHA-256, SHA-256) where the browser offers it; browsers offer it only
// to secure contexts (HTTPS, or localhost), and a module on the LAN is plain
// http://192.168.x.x, so the same functions in plain JavaScript (FIPS 180-4, RFC 2104, RFC
// 8018) stand in for it there. A browser, or node >= 18.
"use strict";

(function (root) {
  const text = new TextEncoder();

  // SHA-256's constants (FIPS 180-4 §4.2.2, §5.3.3): the first 32 bits of the fractional parts
  // of the cube roots of the first 64 primes, and of the square roots of the first 8.
  const K = new Uint32Array(64);
  const H0 = new Uint32Array(8);
  (function () {
    const frac = (x) => ((x - Math.floor(x)) * 0x100000000) >>> 0;
    for (let p = 2, n = 0; n < 64; p++) {
      let prime = true;
      for (let d = 2; d * d <= p; d++) if (p % d === 0) prime = false;
      if (!prime) continue;
      if (n < 8) H0[n] = frac(Math.sqrt(p));
      K[n++] = frac(Math.cbrt(p));
    }
  })();

  const ror = (x, n) => (x >>> n) | (x << (32 - n));
  const W = new Uint32Array(64);

  // One 64-byte block at `at` of `bytes` into the state `h` (FIPS 180-4 §6.2.2).
  function compress(h, bytes, at) {
    for (let i = 0; i < 16; i++) {
      const j = at + 4 * i;
      W[i] = (bytes[j] << 24) | (bytes[j + 1] << 16) | (bytes[j + 2] << 8) | bytes[j + 3];
    }
    for (let i = 16; i < 64; i++) {
      const x = W[i - 15], y = W[i - 2];
      const s0 = ror(x, 7) ^ ror(x, 18) ^ (x >>> 3);
      const s1 = ror(y, 17) ^ ror(y, 19) ^ (y >>> 10);
      W[i] = (W[i - 16] + s0 + W[i - 7] + s1) | 0;
    }
    let a = h[0], b = h[1], c = h[2], d = h[3], e = h[4], f = h[5], g = h[6], k = h[7];
    for (let i = 0; i < 64; i++) {
      const t1 = (k + (ror(e, 6) ^ ror(e, 11) ^ ror(e, 25)) + ((e & f) ^ (~e & g)) + K[i] + W[i]) | 0;
      const t2 = ((ror(a, 2) ^ ror(a, 13) ^ ror(a, 22)) + ((a & b) ^ (a & c) ^ (b & c))) | 0;
      k = g;
      g = f;
      f = e;
      e = (d + t1) | 0;
      d = c;
      c = b;
      b = a;
      a = (t1 + t2) | 0;
    }
    const v = [a, b, c, d, e, f, g, k];
    for (let i = 0; i < 8; i++) h[i] = (h[i] + v[i]) | 0;
  }

  // SHA-256 of `data`, continuing from `state` after `before` bytes (a multiple of 64).
  function sha256From(state, before, bytes) {
    const data = new Uint8Array(bytes);
    const h = Uint32Array.from(state);
    const total = Math.ceil((data.length + 9) / 64) * 64;
    const m = new Uint8Array(total);
    m.set(data);
    m[data.length] = 0x80;
    const bits = (before + data.length) * 8;
    const view = new DataView(m.buffer);
    view.setUint32(total - 8, Math.floor(bits / 0x100000000));
    view.setUint32(total - 4, bits >>> 0);
    for (let at = 0; at < total; at += 64) compress(h, m, at);
    const out = new Uint8Array(32);
    const o = new DataView(out.buffer);
    for (let i = 0; i < 8; i++) o.setUint32(4 * i, h[i]);
    return out;
  }

  // HMAC-SHA-256 (RFC 2104) of messages under `key`: the padded key's two blocks once.
  function hmacJs(bytes) {
    const key = new Uint8Array(bytes);
    const k0 = new Uint8Array(64);
    k0.set(key.length > 64 ? sha256From(H0, 0, key) : key);
    const inner = Uint32Array.from(H0), outer = Uint32Array.from(H0);
    compress(inner, k0.map((b) => b ^ 0x36), 0);
    compress(outer, k0.map((b) => b ^ 0x5c), 0);
    return (data) => sha256From(outer, 64, sha256From(inner, 64, data));
  }

  // The two cores: WebCrypto's, and this file's (the same answers, checked in test/).
  const plain = {
    digest: async (data) => sha256From(H0, 0, data),
    hmac: async (key, data) => hmacJs(key)(data),
    // PBKDF2-HMAC-SHA-256 (RFC 8018 §5.2), one 32-byte block.
    pbkdf2: async (password, salt, iterations) => {
      const prf = hmacJs(password);
      const s = new Uint8Array(salt);
      const first = new Uint8Array(s.length + 4);
      first.set(s);
      first[s.length + 3] = 1;
      let u = prf(first);
      const t = u.slice();
      for (let i = 1; i < iterations; i++) {
        u = prf(u);
        for (let j = 0; j < 32; j++) t[j] ^= u[j];
      }
      return t;
    },
  };

  function webCrypto(subtle) {
    return {
      digest: async (data) => new Uint8Array(await subtle.digest("SHA-256", data)),
      hmac: async (key, data) => {
        const k = await subtle.importKey("raw", key, { name: "HMAC", hash: "SHA-256" }, false, ["sign"]);
        return new Uint8Array(await subtle.sign("HMAC", k, data));
      },
      pbkdf2: async (password, salt, iterations) => {
        const base = await subtle.importKey("raw", password, "PBKDF2", false, ["deriveBits"]);
        return new Uint8Array(await subtle.deriveBits({ name: "PBKDF2", hash: "SHA-256", salt, iterations }, base, 256));
      },
    };
  }

  function hex(bytes) {
    return Array.from(new Uint8Array(bytes), (b) => b.toString(16).padStart(2, "0")).join("");
  }

  function unhex(s) {
    if (typeof s !== "string" || s.length % 2 !== 0 || !/^[0-9a-fA-F]*$/.test(s)) {
      throw new Error("not hex: " + s);
    }
    const out = new Uint8Array(s.length / 2);
    for (let i = 0; i < out.length; i++) out[i] = parseInt(s.substr(2 * i, 2), 16);
    return out;
  }

  function concat(parts) {
    const bytes = parts.map((p) => (typeof p === "string" ? text.encode(p) : new Uint8Array(p)));
    const out = new Uint8Array(bytes.reduce((n, b) => n + b.length, 0));
    let at = 0;
    for (const b of bytes) {
      out.set(b, at);
      at += b.length;
    }
    return out;
  }

  // X25519 (RFC 7748 §5) on BigInts: the page's ephemeral key for a password change. Not
  // constant-time; the key lives for one change on the administrator's own PC.
  function x25519(scalar, u) {
    const P = (1n << 255n) - 19n;
    const mod = (a) => ((a % P) + P) % P;
    const little = (bytes) => bytes.reduceRight((n, b) => (n << 8n) | BigInt(b), 0n);
    const k = Uint8Array.from(scalar);
    k[0] &= 248;
    k[31] &= 127;
    k[31] |= 64;
    const uBytes = Uint8Array.from(u);
    uBytes[31] &= 127;
    const n = little(k), x1 = little(uBytes) % P;
    let x2 = 1n, z2 = 0n, x3 = x1, z3 = 1n, swap = 0n;
    for (let t = 254n; t >= 0n; t--) {
      const bit = (n >> t) & 1n;
      if (swap ^ bit) [x2, x3, z2, z3] = [x3, x2, z3, z2];
      swap = bit;
      const a = mod(x2 + z2), aa = (a * a) % P, b = mod(x2 - z2), bb = (b * b) % P, e = mod(aa - bb);
      const c = mod(x3 + z3), d = mod(x3 - z3), da = (d * a) % P, cb = (c * b) % P;
      x3 = mod((da + cb) * (da + cb));
      z3 = mod(x1 * mod((da - cb) * (da - cb)));
      x2 = (aa * bb) % P;
      z2 = mod(e * (aa + 121665n * e));
    }
    if (swap) [x2, x3, z2, z3] = [x3, x2, z3, z2];
    // z2^(p-2) is its inverse (Fermat).
    let inverse = 1n, base = z2, exp = P - 2n;
    while (exp > 0n) {
      if (exp & 1n) inverse = (inverse * base) % P;
      base = (base * base) % P;
      exp >>= 1n;
    }
    let r = (x2 * inverse) % P;
    const out = new Uint8Array(32);
    for (let i = 0; i < 32; i++, r >>= 8n) out[i] = Number(r & 255n);
    return out;
  }

  const BASE_POINT = Uint8Array.from({ length: 32 }, (_, i) => (i === 0 ? 9 : 0));

  // The API on one core.
  function api(core) {
    const hmac = (key, parts) => core.hmac(key, concat(parts));

    function xor(a, b) {
      return a.map((x, i) => x ^ b[i]);
    }

    // The iteration counts a module accepts (protocol/src/auth.rs): the challenge is not signed,
    // so a forger could ask for a weak count, or one that hangs a phone.
    const MIN_ITERATIONS = 4096;
    const MAX_ITERATIONS = 10000000;

    // SaltedPassword, then ClientKey, StoredKey and ServerKey (RFC 5802 §3 with SHA-256).
    async function deriveKeys(password, salt, iterations) {
      if (!Number.isInteger(iterations) || iterations < MIN_ITERATIONS || iterations > MAX_ITERATIONS) {
        throw new Error("the module asked for " + iterations + " iterations: refused");
      }
      const salted = await core.pbkdf2(text.encode(password), salt, iterations);
      const clientKey = await hmac(salted, ["Client Key"]);
      const storedKey = await core.digest(clientKey);
      const serverKey = await hmac(salted, ["Server Key"]);
      return { clientKey, storedKey, serverKey };
    }

    // ClientProof = ClientKey XOR HMAC(StoredKey, AuthMessage).
    async function proof(keys, message) {
      return xor(keys.clientKey, await hmac(keys.storedKey, message));
    }

    // A domain tag (protocol/src/auth.rs `domain_tag!`): the label's length in a byte, then the
    // label, at the start of every message this page signs, proves or seals with.
    function tag(label) {
      const bytes = text.encode(label);
      return [bytes.length, ...bytes];
    }

    function loginMessage(mac, moduleNonce, pageNonce) {
      return [tag("RDAQ web login"), mac, moduleNonce, pageNonce];
    }

    // Whether the module's answer to a login is signed with the ServerKey of this password.
    async function loginSignatureIsRight(keys, message, session, signature) {
      const expected = await hmac(keys.serverKey, message.concat([session]));
      return hex(expected) === hex(signature);
    }

    async function sessionKey(keys, moduleNonce, pageNonce) {
      return hmac(keys.clientKey, [tag("RDAQ web session"), moduleNonce, pageNonce]);
    }

    // HMAC(key, tag("RDAQ web request\n") METHOD "\n" target "\n" counter "\n" body).
    async function requestSignature(key, method, target, counter, body) {
      return hmac(key, [tag("RDAQ web request\n"), method, "\n", target, "\n", String(counter), "\n", body || ""]);
    }

    // protocol/src/auth.rs `seal`: XOR with HMAC(HMAC(shared, context), tag("RDAQ seal") || block).
    async function seal(shared, context, data) {
      const key = await hmac(shared, context);
      const out = Uint8Array.from(data);
      for (let block = 0; block * 32 < out.length; block++) {
        const stream = await hmac(key, [tag("RDAQ seal"), [block]]);
        for (let i = 0; i < 32 && block * 32 + i < out.length; i++) out[block * 32 + i] ^= stream[i];
      }
      return out;
    }

    // What the module stores of a password (protocol/src/auth.rs `Credential::encode`): salt,
    // iterations (big-endian), StoredKey, ServerKey.
    async function credential(password, salt, iterations) {
      const keys = await deriveKeys(password, salt, iterations);
      const count = [iterations >>> 24, (iterations >>> 16) & 255, (iterations >>> 8) & 255, iterations & 255];
      return concat([salt, count, keys.storedKey, keys.serverKey]);
    }

    // A password change (docs/web.md): the module's ephemeral key, checked against its proof
    // under the session key; the new credential sealed under the key agreed with a fresh one of
    // the page's. `secret` and `salt` are random (the caller's).
    async function sealPassword(sessionKey, modulePublic, proofOfKey, password, secret, salt, iterations) {
      const expected = await hmac(sessionKey, [tag("RDAQ web agreement"), modulePublic]);
      if (hex(expected) !== hex(proofOfKey)) throw new Error("the module's key is not signed by this session");
      const shared = x25519(secret, modulePublic);
      const sealed = await seal(shared, [tag("RDAQ web new credential"), modulePublic], await credential(password, salt, iterations));
      return { module: hex(modulePublic), public: hex(x25519(secret, BASE_POINT)), sealed: hex(sealed) };
    }

    return {
      hex, unhex, deriveKeys, proof, loginMessage, loginSignatureIsRight, sessionKey, requestSignature, core,
      x25519, BASE_POINT, seal, credential, sealPassword, tag,
    };
  }

  if (typeof module !== "undefined" && module.exports) {
    // node: WebCrypto's, and the plain one as `plain` (test/ checks both).
    module.exports = api(webCrypto(require("node:crypto").webcrypto.subtle));
    module.exports.plain = api(plain);
  } else {
    root.RdaqAuth = api(root.crypto && root.crypto.subtle ? webCrypto(root.crypto.subtle) : plain);
  }
})(typeof globalThis !== "undefined" ? globalThis : this);
