// The web console's authentication, the page's side (docs/web.md, "Authentication"): the
// password never leaves the page, the session key never leaves this tab's memory.
// Plain JavaScript on WebCrypto (PBKDF2, HMAC-SHA-256, SHA-256): a browser, or node >= 18.
"use strict";

(function (root) {
  const subtle = (root.crypto && root.crypto.subtle) || require("node:crypto").webcrypto.subtle;
  const text = new TextEncoder();

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

  async function hmac(key, parts) {
    const k = await subtle.importKey("raw", key, { name: "HMAC", hash: "SHA-256" }, false, ["sign"]);
    return new Uint8Array(await subtle.sign("HMAC", k, concat(parts)));
  }

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
    const base = await subtle.importKey("raw", text.encode(password), "PBKDF2", false, ["deriveBits"]);
    const salted = new Uint8Array(
      await subtle.deriveBits({ name: "PBKDF2", hash: "SHA-256", salt, iterations }, base, 256),
    );
    const clientKey = await hmac(salted, ["Client Key"]);
    const storedKey = new Uint8Array(await subtle.digest("SHA-256", clientKey));
    const serverKey = await hmac(salted, ["Server Key"]);
    return { clientKey, storedKey, serverKey };
  }

  // ClientProof = ClientKey XOR HMAC(StoredKey, AuthMessage).
  async function proof(keys, message) {
    return xor(keys.clientKey, await hmac(keys.storedKey, message));
  }

  function loginMessage(mac, moduleNonce, pageNonce) {
    return ["RDAQ web login", mac, moduleNonce, pageNonce];
  }

  // Whether the module's answer to a login is signed with the ServerKey of this password.
  async function loginSignatureIsRight(keys, message, session, signature) {
    const expected = await hmac(keys.serverKey, message.concat([session]));
    return hex(expected) === hex(signature);
  }

  async function sessionKey(keys, moduleNonce, pageNonce) {
    return hmac(keys.clientKey, ["RDAQ web session", moduleNonce, pageNonce]);
  }

  // HMAC(key, "RDAQ web request\n" METHOD "\n" target "\n" counter "\n" body).
  async function requestSignature(key, method, target, counter, body) {
    return hmac(key, ["RDAQ web request\n", method, "\n", target, "\n", String(counter), "\n", body || ""]);
  }

  const api = { hex, unhex, deriveKeys, proof, loginMessage, loginSignatureIsRight, sessionKey, requestSignature };
  if (typeof module !== "undefined" && module.exports) module.exports = api;
  else root.RdaqAuth = api;
})(typeof globalThis !== "undefined" ? globalThis : this);
