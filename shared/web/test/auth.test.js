// The page's authentication (../auth.js) against values computed elsewhere: RFC 7677 §3's
// SCRAM-SHA-256 example, and a web login and a request signature computed with Python's
// hashlib and hmac (the same values check the module's side, protocol/src/web.rs).
// Run: node shared/web/test/auth.test.js (scripts/test runs it).
"use strict";

const assert = require("node:assert/strict");
const auth = require("../auth.js");
const { hex, unhex } = auth;

const checks = [];
const check = (name, f) => checks.push([name, f]);

check("RFC 7677 §3: the proof and the server signature of user/pencil", async () => {
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

check("a web login as computed with Python: proof, session key, the module's signature", async () => {
  const salt = Uint8Array.from({ length: 16 }, (_, i) => i);
  const keys = await auth.deriveKeys("correct horse battery", salt, 4096);
  assert.equal(hex(keys.storedKey), "0d2391706e1d354c401d3128e412f6d32992a0b82df02f232d9d3d4be5545653");
  assert.equal(hex(keys.serverKey), "f612eb7e77fbcef0ad0c1f5dae455790c814b1de2fa477e0e584090eb6da677d");
  const mac = unhex("020000835001");
  const moduleNonce = Uint8Array.from({ length: 16 }, (_, i) => 0xa0 + i);
  const pageNonce = Uint8Array.from({ length: 16 }, (_, i) => 0x10 + i);
  const message = auth.loginMessage(mac, moduleNonce, pageNonce);
  assert.equal(hex(await auth.proof(keys, message)), "61ac8d6e4f6756c44e681d6e4ce8c999ae490853372bea16b87c795885457484");
  assert.equal(
    hex(await auth.sessionKey(keys, moduleNonce, pageNonce)),
    "0483f2f4f46283278fe99d3e2a5881141d117796b1d06a958ce5336bc0bb0d84",
  );
  const session = unhex("0102030405060708");
  const signature = unhex("9dd2da6fad6dfda31c427b090e9dab6347de32a1948608f11eb3f2ca5db68fba");
  assert.ok(await auth.loginSignatureIsRight(keys, message, session, signature));
  signature[0] ^= 1;
  assert.ok(!(await auth.loginSignatureIsRight(keys, message, session, signature)), "a forged answer is seen");
});

check("a request signature as computed with Python", async () => {
  const key = Uint8Array.from({ length: 32 }, (_, i) => i);
  const signature = await auth.requestSignature(key, "PUT", "/api/v1/do/0?x=1", 42, '{"on":true}');
  assert.equal(hex(signature), "2fee5c3589aefbefbc31f7fc28dcdec936c9ff5754f1aae3ad59f4752de51e22");
  assert.notEqual(hex(await auth.requestSignature(key, "PUT", "/api/v1/do/0?x=1", 43, '{"on":true}')), hex(signature));
});

check("an iteration count outside 4096..10000000 is refused", async () => {
  const salt = new Uint8Array(16);
  await assert.rejects(auth.deriveKeys("pencil", salt, 4095));
  await assert.rejects(auth.deriveKeys("pencil", salt, 10000001));
  await assert.rejects(auth.deriveKeys("pencil", salt, "4096"));
});

check("hex in and out; junk refused", async () => {
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
