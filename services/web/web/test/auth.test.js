// The page's authentication (../auth.js) against values computed elsewhere: RFC 7677 §3's
// SCRAM-SHA-256 example, and a web login and a request signature computed with Python's
// hashlib and hmac (the same values check the module's side, protocol/src/web.rs).
// Each check runs twice: on WebCrypto, and on the page's own SHA-256, HMAC and PBKDF2 (what a
// browser uses on plain http://, where it offers no WebCrypto), which is also checked against
// FIPS 180-2, RFC 4231 and RFC 7914's published values and against WebCrypto on random input.
// Run: node services/web/web/test/auth.test.js (scripts/test runs it).
"use strict";

const assert = require("node:assert/strict");
const base = require("../auth.js");
const { hex, unhex } = base;
const cores = [
  ["WebCrypto", base],
  ["plain JS", base.plain],
];

const checks = [];
const check = (name, f) => {
  for (const [label, auth] of cores) checks.push([`${name} (${label})`, () => f(auth)]);
};
const once = (name, f) => checks.push([name, f]);
const bytes = (s) => new TextEncoder().encode(s);

once("plain SHA-256: FIPS 180-2 appendix B, one and two blocks", async () => {
  const d = base.plain.core.digest;
  assert.equal(hex(await d(bytes("abc"))), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
  assert.equal(
    hex(await d(bytes("abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq"))),
    "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1",
  );
});

once("plain HMAC-SHA-256: RFC 4231 cases 2 and 6 (a key longer than a block)", async () => {
  const h = base.plain.core.hmac;
  assert.equal(
    hex(await h(bytes("Jefe"), bytes("what do ya want for nothing?"))),
    "5bdcc146bf60754e6a042426089575c75a003f089d2739839dec58b964ec3843",
  );
  assert.equal(
    hex(await h(new Uint8Array(131).fill(0xaa), bytes("Test Using Larger Than Block-Size Key - Hash Key First"))),
    "60e431591ee0b67f0d8a26aacbf5b77f8e0bc6213728c5140546040f0ee37f54",
  );
});

once("plain PBKDF2-HMAC-SHA-256: RFC 7914 §11 (the first 32 bytes), 1 and 80000 iterations", async () => {
  const p = base.plain.core.pbkdf2;
  assert.equal(hex(await p(bytes("passwd"), bytes("salt"), 1)), "55ac046e56e3089fec1691c22544b605f94185216dde0465e68b9d57c20dacbc");
  assert.equal(hex(await p(bytes("Password"), bytes("NaCl"), 80000)), "4ddcd8f60b98be21830cee5ef22701f9641a4418d04c0414aeff08876b34ab56");
});

once("plain and WebCrypto agree on 200 random inputs of 0-300 bytes, keys of 1-150 (digest, HMAC, PBKDF2)", async () => {
  const random = (n) => require("node:crypto").randomBytes(n);
  for (let i = 0; i < 200; i++) {
    const [data, key] = [random(Math.floor(Math.random() * 300)), random(1 + Math.floor(Math.random() * 150))];
    assert.equal(hex(await base.plain.core.digest(data)), hex(await base.core.digest(data)), `digest of ${data.length} bytes`);
    assert.equal(hex(await base.plain.core.hmac(key, data)), hex(await base.core.hmac(key, data)), `hmac ${key.length}/${data.length}`);
    if (i % 20 === 0) {
      const n = 1 + Math.floor(Math.random() * 50);
      assert.equal(hex(await base.plain.core.pbkdf2(key, data, n)), hex(await base.core.pbkdf2(key, data, n)), "pbkdf2");
    }
  }
});

check("RFC 7677 §3: the proof and the server signature of user/pencil", async (auth) => {
  const keys = await auth.deriveKeys("pencil", unhex("5b6d99689d12358eeca04b141236fa81"), 4096);
  const message = [
    "n=user,r=rOprNGfwEbeRWgbNEkqO,r=rOprNGfwEbeRWgbNEkqO%hvYDpWUa2RaTCAfuxFIlj)hNlF$k0," +
      "s=W22ZaJ0SNY7soEsUEjb6gQ==,i=4096,c=biws,r=rOprNGfwEbeRWgbNEkqO%hvYDpWUa2RaTCAfuxFIlj)hNlF$k0",
  ];
  assert.equal(hex(await auth.proof(keys, message)), "747cdb65aa56224e2352137e52d7bdcad6a0f738df30782caa69a2cfb0277554");
  assert.ok(
    await auth.loginSignatureIsRight(
      keys,
      message,
      new Uint8Array(0),
      unhex("eabae24d1062db75a9451ff0b6ea7e98c8546549ff741e672d3251b2397de46e"),
    ),
  );
});

check("a web login as computed with Python: proof, session key, the module's signature", async (auth) => {
  const salt = Uint8Array.from({ length: 16 }, (_, i) => i);
  const keys = await auth.deriveKeys("correct horse battery", salt, 4096);
  assert.equal(hex(keys.storedKey), "0d2391706e1d354c401d3128e412f6d32992a0b82df02f232d9d3d4be5545653");
  assert.equal(hex(keys.serverKey), "f612eb7e77fbcef0ad0c1f5dae455790c814b1de2fa477e0e584090eb6da677d");
  const mac = unhex("020000835001");
  const moduleNonce = Uint8Array.from({ length: 16 }, (_, i) => 0xa0 + i);
  const pageNonce = Uint8Array.from({ length: 16 }, (_, i) => 0x10 + i);
  const message = auth.loginMessage(mac, moduleNonce, pageNonce);
  assert.equal(hex(await auth.proof(keys, message)), "7a3e1ebd5d67c927c6debfa2d27218b75556031993e96cc595fb7a3a600b14ab");
  assert.equal(
    hex(await auth.sessionKey(keys, moduleNonce, pageNonce)),
    "d6d8ccb09cca07a18fc54cbddaf738b925162097f2bbfa5e93c4d13fbbd0f5c8",
  );
  const session = unhex("0102030405060708");
  const signature = unhex("976a80013e4a26e292344d774f87d908cf31003920ed2039ff0f7070ec3e2564");
  assert.ok(await auth.loginSignatureIsRight(keys, message, session, signature));
  signature[0] ^= 1;
  assert.ok(!(await auth.loginSignatureIsRight(keys, message, session, signature)), "a forged answer is seen");
});

check("a request signature as computed with Python", async (auth) => {
  const key = Uint8Array.from({ length: 32 }, (_, i) => i);
  const signature = await auth.requestSignature(key, "PUT", "/api/v1/do/0?x=1", 42, '{"on":true}');
  assert.equal(hex(signature), "ceb9b08e80757b9fddbca501018dd4e4695fe33005480973fd7dd202d695d6a4");
  assert.notEqual(hex(await auth.requestSignature(key, "PUT", "/api/v1/do/0?x=1", 43, '{"on":true}')), hex(signature));
});

check("an iteration count outside 4096..10000000 is refused", async (auth) => {
  const salt = new Uint8Array(16);
  await assert.rejects(auth.deriveKeys("pencil", salt, 4095));
  await assert.rejects(auth.deriveKeys("pencil", salt, 10000001));
  await assert.rejects(auth.deriveKeys("pencil", salt, "4096"));
});

once("X25519: RFC 7748 §5.2's first vector and §6.1's Diffie-Hellman", async () => {
  const x = base.x25519;
  assert.equal(
    hex(x(unhex("a546e36bf0527c9d3b16154b82465edd62144c0ac1fc5a18506a2244ba449ac4"),
      unhex("e6db6867583030db3594c1a424b15f7c726624ec26b3353b10a903a6d0ab1c4c"))),
    "c3da55379de9c6908e94ea4df28d084f32eccf03491c71f754b4075577a28552",
  );
  const alice = unhex("77076d0a7318a57d3c16c17251b26645df4c2f87ebc0992ab177fba51db92c2a");
  const bob = unhex("5dab087e624a8a4b79e17f8b83800ee66f3bb1292618b6fd1c2f8b27ff88e0eb");
  const [alicePublic, bobPublic] = [x(alice, base.BASE_POINT), x(bob, base.BASE_POINT)];
  assert.equal(hex(alicePublic), "8520f0098930a754748b7ddcb43ef75a0dbf3a0d26381af4eba4a98eaa9b4e6a");
  assert.equal(hex(bobPublic), "de9edb7d7b7dc1b4d35b61c2ece435373f8343c85b78674dadfc7e146f882b4f");
  const shared = "4a5d9d5ba4ce2de1728e3bf480350f25e07e21c947d19e3376f09b3c1e161742";
  assert.equal(hex(x(alice, bobPublic)), shared);
  assert.equal(hex(x(bob, alicePublic)), shared);
});

check("a sealed credential as computed with Python: the seal, the credential, the key's proof", async (auth) => {
  const shared = Uint8Array.from({ length: 32 }, (_, i) => i);
  const modulePublic = new Uint8Array(32).fill(0x42);
  const data = Uint8Array.from({ length: 84 }, (_, i) => 100 + i);
  const sealed = await auth.seal(shared, [auth.tag("RDAQ web new credential"), modulePublic], data);
  assert.equal(hex(sealed), "bf5f16125ed76787080499b7ca80eab569c3df1663acef47bc0667389ac70dc28d8bfa835024675d9934790d00d54347"
    + "c35ca4a6f70ec1f173fc61b74d4721264776de1a8bb67613bc19ab2db61ee4c7d0b9fdfb");
  const credential = await auth.credential("correct horse", bytes("0123456789abcdef"), 4096);
  assert.equal(hex(credential), "3031323334353637383961626364656600001000b5281eb63616e5242537323124028caf2b83187f129f0e6859c8f5"
    + "78e5b467226db67574932061868a291d5f535a061e4589ce2f4e418e3253c16e92c6b5b7bd");
  // The module's key must carry its proof under the session key (Python: ec1fb2...).
  const session = new Uint8Array(32).fill(7);
  const proof = unhex("ec1fb2129c11442deaef2821725e567a2db40a30cf03e973a7a098c54120ff53");
  const secret = new Uint8Array(32).fill(9);
  const done = await auth.sealPassword(session, modulePublic, proof, "correct horse", secret, bytes("0123456789abcdef"), 4096);
  assert.equal(done.public, hex(base.x25519(secret, base.BASE_POINT)));
  assert.equal(done.module, hex(modulePublic), "says which of the module's keys it was sealed for");
  const forged = Uint8Array.from(proof);
  forged[0] ^= 1;
  await assert.rejects(auth.sealPassword(session, modulePublic, forged, "correct horse", secret, bytes("0123456789abcdef"), 4096));
});

check("a domain tag is the label's length in a byte, then the label (protocol's domain_tag!)", async (auth) => {
  assert.deepEqual(auth.tag("RDAQ seal"), [9, 0x52, 0x44, 0x41, 0x51, 0x20, 0x73, 0x65, 0x61, 0x6c]);
});

check("hex in and out; junk refused", async (auth) => {
  assert.equal(hex(unhex("00ab1F")), "00ab1f");
  assert.throws(() => unhex("00ab1"));
  assert.throws(() => unhex("zz"));
});

(async () => {
  let failed = 0;
  for (const [name, f] of checks) {
    try {
      await f();
      console.log(`web-js ${name} ... ok`);
    } catch (e) {
      failed++;
      console.log(`web-js ${name} ... FAILED: ${e.message}`);
    }
  }
  console.log(`web-js: ${checks.length - failed} passed, ${failed} failed`);
  process.exit(failed === 0 ? 0 : 1);
})();
