// The web console's pages (docs/web.md): plain JavaScript, no framework. Reads need no login;
// every change is a request signed with the session key (auth.js), which lives only in this
// tab's memory. English and Simplified Chinese, from the browser's language, with a switch.
"use strict";

(function () {
  const A = window.RdaqAuth;

  const TEXT = {
    en: {
      status: "Status", io: "Live I/O", settings: "Settings", login: "Log in", logout: "Log out",
      password: "Password", cancel: "Cancel", model: "Model", firmware: "Firmware", mac: "MAC address",
      uptime: "Uptime", connections: "Modbus connections", requests: "Requests", exceptions: "Exceptions",
      auth_failures: "Failed logins", last_failed_source: "Last failed login from",
      channel: "Channel", value: "Value", raw: "Raw", enabled: "Enabled", input_type: "Input type",
      cjc: "Cold junction", cjc_offset: "Cold-junction offset (°C)", open_value: "Open input reads",
      upscale: "upscale (FFFFh)", downscale: "downscale (0000h)", enable_mask: "Enabled channels",
      di: "Digital inputs", do: "Digital outputs", state: "State", mode: "Mode", counter: "Counter",
      frequency: "Frequency (Hz)", latch: "Latch", overflow: "Overflow", on: "on", off: "off",
      normal: "normal", "latch rising": "latch, rising edge", "latch falling": "latch, falling edge",
      pulse: "pulse output", low_width: "Low (0.1 ms)", high_width: "High (0.1 ms)",
      pulses: "Pulses (0: continuous)", timeout: "Host watchdog (0.1 s, 0: off)", watchdog: "Host watchdog",
      saved: "Saved.", "need login": "Log in to change anything.", "wrong password": "Wrong password.",
      "logged in": "Logged in.", "logged out": "Logged out.", "not a number": "Not a number: nothing written.",
      "no answer": "The module does not answer.",
      ok: "ok", open: "open", "over range": "over range", "under range": "under range", disabled: "disabled",
      "front-end fault": "front-end fault", "cold-junction fault": "cold-junction fault",
      thermocouple: "thermocouple", voltage: "voltage", current: "current",
      network: "Network", security: "Security", ip: "IP address", mask: "Subnet mask", gateway: "Gateway",
      modbus_port: "Modbus/TCP port", http_port: "Web console port", stored: "Stored settings", running: "In force now", save: "Save",
      restart: "Restart the module", "restart needed": "New settings are stored: they take effect after a restart.",
      restarting: "The module restarts. Open it again at its new address if you changed it.",
      "allow-list": "Modbus write allow-list", networks: "Networks (a.b.c.d/n), empty: any client may write",
      "login to see": "Log in to see and change the allow-list.",
      new_password: "New password", repeat_password: "Repeat it", change_password: "Change the password",
      "password-sealed": "The password never leaves this page: the module receives only its salted keys, sealed with a key agreed for this change.",
      "too short": "At least 8 characters.", "not the same": "The two passwords differ.",
      "password changed": "Password changed: log in again with the new one.",
      "login first": "Log in to change the password.",
      "set a password first": "Set a password of your own first: the factory one, which anyone knows, allows neither restricted writes nor updates.",
      "image file": "Signed image file (.rdq)", upload: "Upload", "choose a file": "Choose an image file first.",
      "no updates here": "This module takes no firmware updates here (no update partition).",
      "login to update": "Log in to update the firmware.", "not a signed image file": "Not a signed image file (remodaq sign).",
      sending: "Sending…", verifying: "The module verifies the image…", verified: "Verified and marked:",
      "restarting into it": "The module restarts into it.",
      "finish unanswered": "No answer to the finish: waiting to see whether the module restarts into the image.", "now running": "The module now runs firmware",
      "not back": "The module did not answer again within 3 minutes.",
      "image-signed": "The module checks the image's signature against its own key and refuses an older release; the running firmware stays until the whole image is verified.",
    },
    zh: {
      status: "状态", io: "实时 I/O", settings: "设置", login: "登录", logout: "退出登录",
      password: "密码", cancel: "取消", model: "型号", firmware: "固件版本", mac: "MAC 地址",
      uptime: "运行时间", connections: "Modbus 连接数", requests: "请求数", exceptions: "异常数",
      auth_failures: "登录失败次数", last_failed_source: "最近失败登录来源",
      channel: "通道", value: "数值", raw: "原始码", enabled: "启用", input_type: "输入类型",
      cjc: "冷端温度", cjc_offset: "冷端偏移 (°C)", open_value: "断线时读数",
      upscale: "上限 (FFFFh)", downscale: "下限 (0000h)", enable_mask: "启用的通道",
      di: "数字输入", do: "数字输出", state: "状态", mode: "模式", counter: "计数",
      frequency: "频率 (Hz)", latch: "锁存", overflow: "溢出", on: "开", off: "关",
      normal: "普通", "latch rising": "上升沿锁存", "latch falling": "下降沿锁存",
      pulse: "脉冲输出", low_width: "低电平 (0.1 ms)", high_width: "高电平 (0.1 ms)",
      pulses: "脉冲数 (0: 连续)", timeout: "主机看门狗 (0.1 s, 0: 关闭)", watchdog: "主机看门狗",
      saved: "已保存。", "need login": "请先登录再修改。", "wrong password": "密码错误。",
      "logged in": "已登录。", "logged out": "已退出登录。", "not a number": "不是数字：未写入。",
      "no answer": "模块没有应答。",
      ok: "正常", open: "断线", "over range": "超上限", "under range": "超下限", disabled: "已禁用",
      "front-end fault": "前端故障", "cold-junction fault": "冷端故障",
      thermocouple: "热电偶", voltage: "电压", current: "电流",
      network: "网络", security: "安全", ip: "IP 地址", mask: "子网掩码", gateway: "网关",
      modbus_port: "Modbus/TCP 端口", http_port: "网页控制台端口", stored: "已保存的设置", running: "当前生效", save: "保存",
      restart: "重启模块", "restart needed": "新设置已保存，重启后生效。",
      restarting: "模块正在重启。如已更改地址，请用新地址重新打开。",
      "allow-list": "Modbus 写入白名单", networks: "网络 (a.b.c.d/n)，为空时任何客户端都可写入",
      "login to see": "登录后可查看和修改白名单。",
      new_password: "新密码", repeat_password: "再输入一次", change_password: "修改密码",
      "password-sealed": "密码不会离开本页面：模块只收到加盐后的密钥，并以本次协商的密钥加密。",
      "too short": "至少 8 个字符。", "not the same": "两次输入的密码不一致。",
      "password changed": "密码已修改，请用新密码重新登录。", "login first": "登录后可修改密码。",
      "set a password first": "请先修改出厂密码。", "ask for the module's key first": "请重试修改密码。",
      "image file": "已签名的固件文件 (.rdq)", upload: "上传", "choose a file": "请先选择固件文件。",
      "no updates here": "此模块不能在此更新固件（没有更新分区）。", "login to update": "登录后可更新固件。",
      "not a signed image file": "不是已签名的固件文件 (remodaq sign)。", sending: "正在发送…",
      verifying: "模块正在校验固件…", verified: "已校验并标记：", "restarting into it": "模块将重启并运行新固件。",
      "finish unanswered": "完成请求未获应答：正在等待模块是否以新固件重启。",
      "now running": "模块当前运行固件", "not back": "模块 3 分钟内没有再次应答。",
      "image-signed": "模块用自己的密钥校验固件签名，并拒绝旧版本；在整个固件校验通过之前，当前固件保持不变。",
      "another upload is under way": "另一个上传正在进行。", "no upload of this session": "本会话没有进行中的上传。",
      "not the next chunk": "数据块顺序错误。", "the image is not all sent": "固件尚未全部发送。",
      "this module takes no updates here": "此模块不能在此更新固件。",
      "not an image for this module (model, size or format)": "不是本模块的固件（型号、大小或格式不符）。",
      "the image's security counter is below the module's (an older release)": "固件的安全计数低于模块的（旧版本）。",
      "the signature does not match (another key, or a changed file)": "签名不符（其他密钥，或文件被修改）。",
      "the module could not write the update": "模块无法写入更新。",
      "not a usable password": "模块不接受该密码。",
      "not a usable value": "该值不可用。", "at most 4 networks, a.b.c.d/n each": "最多 4 个网络，格式 a.b.c.d/n。",
      "the settings could not be stored": "设置无法保存。",
      // The module's error texts (services/web/src/).
      unsigned: "请求未签名。", "no session": "会话已结束，请重新登录。", "stale counter": "过期的请求（重放）。",
      "bad signature": "签名错误。", "value refused": "模块拒绝了该值。", "not a value of this field": "该字段不接受此值。",
      "the field is read-only": "该字段只读。", "no such item": "没有该通道。", "no such resource": "没有该资源。",
      "too many wrong passwords: wait": "密码错误次数过多，请稍候。", "request from another origin": "来自其他来源的请求。",
      "reach the module by its address": "请使用模块的 IP 地址访问。", "body too large": "请求过大。",
      "target too long": "请求地址过长。", "refused by the module": "模块拒绝了该请求。",
      "the module could not apply it": "模块无法执行。", "the module is not ready for logins": "模块尚未准备好登录。",
      "challenge unknown, used or expired": "登录挑战无效或已过期，请重试。", "address not mapped for this access": "该地址不可访问。",
      "the module's signature is wrong": "模块的签名错误：可能有人冒充该模块。",
    },
  };

  // Spec §2.2: the 8318's input types, by code.
  const INPUT_TYPES = [
    [0x00, "±15 mV"], [0x01, "±50 mV"], [0x02, "±100 mV"], [0x03, "±500 mV"], [0x04, "±1 V"],
    [0x05, "±2.5 V"], [0x06, "±20 mA"], [0x0e, "J -200…1100 °C"], [0x0f, "K -250…1400 °C"],
    [0x10, "T -250…400 °C"], [0x11, "E -250…900 °C"], [0x12, "R 0…1750 °C"], [0x13, "S 0…1750 °C"],
    [0x14, "B 0…1800 °C"], [0x15, "N -250…1300 °C"], [0x16, "C 0…2310 °C"], [0x17, "L -200…800 °C"],
    [0x18, "M -200…100 °C"],
  ];
  const DI_MODES = ["normal", "counter", "latch rising", "latch falling", "frequency"];
  const DO_MODES = ["normal", "pulse"];
  // protocol/src/update.rs: a signed image file's header.
  const HEADER_LEN = 146;

  let lang = (localStorage.getItem("rdaq-lang") || navigator.language || "en").toLowerCase().startsWith("zh") ? "zh" : "en";
  let identity = null;
  let session = null; // { id, key, counter }: this tab's memory only
  let timer = null;

  const t = (key) => (TEXT[lang] && TEXT[lang][key]) || TEXT.en[key] || key;
  const $ = (id) => document.getElementById(id);
  const page = $("page");

  function el(tag, attrs, ...children) {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (k.startsWith("on")) e.addEventListener(k.slice(2), v);
      else if (v !== undefined && v !== null && v !== false) e.setAttribute(k, v === true ? "" : v);
    }
    for (const c of children.flat(Infinity)) e.append(c instanceof Node ? c : String(c));
    return e;
  }

  function say(text, error) {
    const m = $("message");
    m.textContent = text;
    m.className = error ? "error" : "";
  }

  // Every request gives up after 10 s (a module gone quiet must not hold the page).
  const WAIT = () => AbortSignal.timeout(10000);

  async function get(path) {
    const r = await fetch("/api/v1/" + path, { cache: "no-store", signal: WAIT() });
    const body = await r.json().catch(() => ({}));
    if (!r.ok) throw new Error(t(body.error || String(r.status)));
    return body;
  }

  // Whether a request failed for want of an answer (the network, or its time ran out), not by
  // the module's refusal.
  const unanswered = (e) => e instanceof TypeError || e.name === "TimeoutError" || e.name === "AbortError";

  // Signed requests go one after the other: each counter must reach the module after the one
  // before it (a later one arriving first would make the earlier one stale).
  let signing = Promise.resolve();
  function signed(method, path, value, whole) {
    const run = signing.then(() => signedNow(method, path, value, whole));
    signing = run.catch(() => {});
    return run.catch((e) => {
      // A refusal is said by signedNow; a request that got no answer is said here.
      if (unanswered(e)) say(t("no answer"), true);
      throw e;
    });
  }

  // A signed request (docs/web.md, "Authentication"): the body is {value} or, for a resource
  // written whole, `whole`. Resolves to the answer's JSON (null for none); a refusal is said.
  async function signedNow(method, path, value, whole) {
    // The session this request is signed in (a logout or login meanwhile does not mix two).
    const s = session;
    if (!s) {
      say(t("need login"), true);
      throw new Error("need login");
    }
    const target = "/api/v1/" + path;
    // Bytes (a firmware image's part) go as they are; anything else as JSON.
    const binary = whole instanceof Uint8Array;
    const body = binary ? whole : whole !== undefined ? JSON.stringify(whole) : value === undefined ? "" : JSON.stringify({ value });
    s.counter += 1;
    const counter = s.counter;
    const signature = await A.requestSignature(s.key, method, target, counter, body);
    const r = await fetch(target, {
      method,
      body: body.length ? body : undefined,
      signal: WAIT(),
      headers: {
        "Content-Type": binary ? "application/octet-stream" : "application/json",
        "X-RDAQ-Session": s.id,
        "X-RDAQ-Counter": String(counter),
        "X-RDAQ-Signature": A.hex(signature),
      },
    });
    if (r.status === 204) return null;
    const answer = await r.json().catch(() => ({}));
    if (r.ok) return answer;
    if (r.status === 401 && answer.error === "no session" && session === s) {
      session = null;
      translate();
    }
    const what = (answer.field ? t(answer.field) + ": " : "") + t(answer.error || String(r.status));
    say(what, true);
    throw new Error(what);
  }

  async function login(password) {
    const c = await (await fetch("/api/v1/session/challenge", { method: "POST" })).json().catch(() => ({}));
    if (!c.nonce) throw new Error(t(c.error || "the module is not ready for logins"));
    const keys = await A.deriveKeys(password, A.unhex(c.salt), c.iterations);
    const mac = A.unhex(identity.mac);
    const nonce = A.unhex(c.nonce);
    const pageNonce = crypto.getRandomValues(new Uint8Array(16));
    const message = A.loginMessage(mac, nonce, pageNonce);
    const proof = await A.proof(keys, message);
    const r = await fetch("/api/v1/session", {
      method: "POST",
      headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ nonce: c.nonce, page_nonce: A.hex(pageNonce), proof: A.hex(proof) }),
    });
    const s = await r.json().catch(() => ({}));
    if (r.status !== 200) throw new Error(t(s.error || String(r.status)));
    // The module proves it knows this password too: a forger on the LAN cannot fake a login.
    if (!(await A.loginSignatureIsRight(keys, message, A.unhex(s.session), A.unhex(s.signature)))) {
      throw new Error(t("the module's signature is wrong"));
    }
    session = { id: s.session, key: await A.sessionKey(keys, nonce, pageNonce), counter: 0 };
  }

  // A control that writes one field when changed.
  function field(path, value, kind, options) {
    const write = async (v) => {
      try {
        await signed("PUT", path, v);
        say(t("saved"));
      } catch (e) {
        show(true);
      }
    };
    if (kind === "select") {
      return el("select", { "aria-label": path, onchange: (e) => write(options.parse ? options.parse(e.target.value) : e.target.value) },
        options.list.map(([v, label]) => el("option", { value: v, selected: String(v) === String(value) }, label)));
    }
    return el("input", {
      "aria-label": path, type: "number", value, step: kind === "decimal" ? "0.01" : "1", required: true,
      onchange: (e) => {
        // An emptied field is no 0 (which would turn the watchdog off, or every channel).
        if (e.target.value === "" || !e.target.validity.valid) {
          say(t("not a number"), true);
          show(true);
        } else {
          write(Number(e.target.value));
        }
      },
    });
  }

  function table(head, rows) {
    return el("table", {}, el("tr", {}, head.map((h) => el("th", {}, h))), rows);
  }

  function statusClass(s) {
    return String(s).split(" ")[0];
  }

  function uptime(s) {
    const d = Math.floor(s / 86400), h = Math.floor(s / 3600) % 24, m = Math.floor(s / 60) % 60;
    return (d ? d + " d " : "") + h + " h " + m + " min";
  }

  // A text field of a form written whole.
  function textField(form, name, value) {
    form[name] = el("input", { "aria-label": name, value: value, spellcheck: "false", autocomplete: "off" });
    return el("label", {}, t(name) + " ", form[name]);
  }

  const PAGES = {
    async status() {
      const d = await get("diagnostics");
      const rows = [
        ["model", identity.name], ["firmware", identity.firmware], ["mac", identity.mac],
        ["uptime", uptime(d.uptime_s)], ["connections", d.connections], ["requests", d.requests],
        ["exceptions", d.exceptions], ["auth_failures", d.auth_failures], ["last_failed_source", d.last_failed_source],
      ];
      return el("dl", {}, rows.map(([k, v]) => [el("dt", {}, t(k)), el("dd", {}, v)]));
    },

    async io() {
      if (identity.model === "8318") {
        const [c, i] = await Promise.all([get("channels"), get("inputs")]);
        const unit = i.type.unit || "";
        return table([t("channel"), t("value"), t("status"), t("raw")], c.channels.map((ch, n) =>
          el("tr", { class: statusClass(ch.status) },
            el("td", {}, n), el("td", { class: "num" }, ch.value === null ? "-" : ch.value.toFixed(3) + " " + unit),
            el("td", {}, t(ch.status)), el("td", { class: "num" }, ch.raw))));
      }
      // One request at a time: the module serves two connections.
      const di = await get("di");
      const dout = await get("do");
      return [
        el("h2", {}, t("di")),
        table([t("channel"), t("state"), t("mode"), t("counter"), t("frequency"), t("latch"), t("overflow")], di.di.map((d, n) =>
          el("tr", {}, el("td", {}, "DI" + n), el("td", { class: d.state ? "on" : "" }, t(d.state ? "on" : "off")),
            el("td", {}, t(d.mode)), el("td", { class: "num" }, d.counter),
            el("td", { class: "num" }, d.frequency === null ? "-" : d.frequency),
            el("td", {}, d.latch ? "●" : ""), el("td", {}, d.overflow ? "●" : "")))),
        el("h2", {}, t("do")),
        table([t("channel"), t("state"), t("mode")], dout.do.map((d, n) =>
          el("tr", {}, el("td", {}, "DO" + n),
            el("td", {}, el("button", {
              class: "toggle" + (d.state ? " on" : ""), "aria-pressed": String(d.state), "aria-label": "DO" + n,
              // The state shown when clicked (the row is updated in place between clicks).
              onclick: (e) => signed("PUT", "do/" + n + "/state", e.currentTarget.getAttribute("aria-pressed") !== "true")
                .then(() => show(), () => {}),
            }, t(d.state ? "on" : "off"))),
            el("td", {}, t(d.mode))))),
      ];
    },

    async settings() {
      if (identity.model === "8318") {
        const i = await get("inputs");
        const types = INPUT_TYPES.map(([code, name]) => [code, name]);
        return el("div", {},
          el("label", {}, t("input_type") + " ", field("inputs/type", i.type.code, "select", { list: types, parse: Number })),
          el("label", {}, t("enable_mask") + " ", field("inputs/enable_mask", i.enable_mask, "number")),
          el("label", {}, t("cjc_offset") + " ", field("inputs/cjc_offset", i.cjc_offset, "decimal")),
          el("label", {}, t("open_value") + " ", field("inputs/open_value", i.open_value, "select",
            { list: [["upscale", t("upscale")], ["downscale", t("downscale")]] })),
          el("p", {}, t("cjc") + ": " + i.cjc + " °C"));
      }
      const [di, dout, w] = await Promise.all([get("di"), get("do"), get("watchdog")]);
      const modes = (list) => ({ list: list.map((m) => [m, t(m)]) });
      return [
        el("h2", {}, t("di")),
        table([t("channel"), t("mode")], di.di.map((d, n) =>
          el("tr", {}, el("td", {}, "DI" + n), el("td", {}, field("di/" + n + "/mode", d.mode, "select", modes(DI_MODES)))))),
        el("h2", {}, t("do")),
        table([t("channel"), t("mode"), t("low_width"), t("high_width"), t("pulses")], dout.do.map((d, n) =>
          el("tr", {}, el("td", {}, "DO" + n),
            el("td", {}, field("do/" + n + "/mode", d.mode, "select", modes(DO_MODES))),
            el("td", {}, field("do/" + n + "/low_width", d.low_width, "number")),
            el("td", {}, field("do/" + n + "/high_width", d.high_width, "number")),
            el("td", {}, field("do/" + n + "/pulses", d.pulses, "number"))))),
        el("h2", {}, t("watchdog")),
        el("label", {}, t("timeout") + " ", field("watchdog/timeout", w.timeout, "number")),
      ];
    },

    // Stored network settings (in force after a restart), as the utility's discovery sets them.
    async network() {
      const n = await get("network");
      const form = {};
      const keys = ["ip", "mask", "gateway", "modbus_port", "http_port"];
      const save = () => {
        const net = Object.fromEntries(keys.map((k) => [k, form[k].value.trim()]));
        net.modbus_port = Number(net.modbus_port);
        net.http_port = Number(net.http_port);
        signed("PUT", "network", undefined, net).then(() => { say(t("saved")); show(true); }, () => {});
      };
      const r = n.running;
      return [
        el("h2", {}, t("stored")),
        keys.map((k) => textField(form, k, n.stored[k])),
        el("button", { onclick: save }, t("save")),
        n.restart_needed ? el("p", { class: "error" }, t("restart needed")) : null,
        el("h2", {}, t("running")),
        el("p", {}, r.ip + " / " + r.mask + ", " + t("gateway") + " " + r.gateway + ", " + t("modbus_port") + " "
          + r.modbus_port + ", " + t("http_port") + " " + r.http_port),
        el("button", { onclick: () => signed("POST", "restart").then(() => say(t("restarting")), () => {}) }, t("restart")),
      ].flat().filter((e) => e);
    },

    // The Modbus write allow-list (shown to a session only, as discovery shows it with the
    // password); the password is changed with the utility.
    // A signed image file (`remodaq sign`: its header, then the firmware) sent a chunk at a
    // time, each a signed request; the module verifies it whole before it marks it, then
    // restarts into it (docs/web.md, "Firmware").
    async firmware() {
      const f = await get("firmware");
      const parts = [el("dl", {}, el("dt", {}, t("firmware")), el("dd", { id: "running-firmware" }, f.firmware))];
      if (!f.updates) return parts.concat(el("p", {}, t("no updates here")));
      if (!session) return parts.concat(el("p", {}, t("login to update")));
      const file = el("input", { type: "file", id: "image-file", accept: ".rdq", "aria-label": "image file" });
      const bar = el("progress", { id: "upload-progress", max: "1", value: "0", "aria-label": "upload progress" });
      const verdict = el("p", { id: "verdict", role: "status" });
      const upload = async (event) => {
        const button = event.currentTarget;
        const chosen = file.files[0];
        if (!chosen) return say(t("choose a file"), true);
        // A verdict of an earlier upload is not this one's.
        say("");
        button.disabled = true;
        try {
          const bytes = new Uint8Array(await chosen.arrayBuffer());
          if (bytes.length <= HEADER_LEN) throw new Error(t("not a signed image file"));
          const firmware = bytes.subarray(HEADER_LEN);
          verdict.textContent = t("sending");
          const begun = await signed("POST", "firmware", undefined, bytes.subarray(0, HEADER_LEN));
          if (begun.length !== firmware.length) throw new Error(t("not a signed image file"));
          bar.max = firmware.length;
          for (let at = 0; at < firmware.length; at += f.chunk) {
            await signed("PUT", "firmware/" + at, undefined, firmware.subarray(at, at + f.chunk));
            bar.value = Math.min(at + f.chunk, firmware.length);
          }
          verdict.textContent = t("verifying");
          // A finish whose answer is lost (the module restarts 3 s after the mark whatever
          // happens to the answer): the version it comes back with says what happened.
          const done = await signed("POST", "firmware/finish").catch((e) => {
            if (unanswered(e)) return null;
            throw e;
          });
          verdict.textContent = done ? t("verified") + " " + done.firmware + ". " + t("restarting into it") : t("finish unanswered");
          // The module restarts: its sessions end. Its firmware version, once it answers again.
          session = null;
          translate();
          for (const deadline = Date.now() + 180000; Date.now() < deadline;) {
            await new Promise((go) => setTimeout(go, 2000));
            const now = await get("identity").catch(() => null);
            if (now && now.firmware === begun.firmware) {
              identity = now;
              $("running-firmware").textContent = now.firmware;
              verdict.textContent = t("now running") + " " + now.firmware + ".";
              say(t("now running") + " " + now.firmware + ".");
              return;
            }
          }
          verdict.textContent = t("not back");
        } catch (e) {
          verdict.textContent = String(e.message || e);
        } finally {
          button.disabled = false;
        }
      };
      return parts.concat(el("label", {}, t("image file") + " ", file),
        el("button", { id: "upload", onclick: upload }, t("upload")), bar, verdict, el("p", {}, t("image-signed")));
    },

    async security() {
      const parts = [el("h2", {}, t("allow-list"))];
      if (!session) {
        parts.push(el("p", {}, t("login to see")));
      } else {
        const a = await signed("GET", "access");
        const form = {};
        const save = () => {
          const networks = form.networks.value.split(/[\s,]+/).filter((x) => x);
          signed("PUT", "access", undefined, { networks }).then(() => { say(t("saved")); show(true); }, () => {});
        };
        parts.push(textField(form, "networks", a.networks.join(", ")), el("button", { id: "save-access", onclick: save }, t("save")));
      }
      parts.push(el("h2", {}, t("password")));
      if (!session) {
        parts.push(el("p", {}, t("login first")));
        return parts;
      }
      const pw = {};
      const input = (name) => (pw[name] = el("input", { type: "password", "aria-label": name, autocomplete: "new-password" }));
      const change = async (event) => {
        const [first, second] = [pw.new_password.value, pw.repeat_password.value];
        if (first.length < 8) return say(t("too short"), true);
        if (first !== second) return say(t("not the same"), true);
        // One change at a time: a second would replace the module's key the first sealed for.
        const button = event.currentTarget;
        button.disabled = true;
        try {
          const s = session;
          const offer = await signed("POST", "password/key");
          // The page's ephemeral key and a fresh salt; 100000 iterations, as the utility sets.
          const sealed = await A.sealPassword(s.key, A.unhex(offer.public), A.unhex(offer.proof), first,
            crypto.getRandomValues(new Uint8Array(32)), crypto.getRandomValues(new Uint8Array(16)), 100000)
            .catch((e) => {
              say(e.message, true);
              throw e;
            });
          await signed("PUT", "password", undefined, sealed);
          if (session === s) session = null;
          translate();
          say(t("password changed"));
          show(true);
        } catch (e) {
          // Said where it failed.
        } finally {
          button.disabled = false;
        }
      };
      parts.push(el("label", {}, t("new_password") + " ", input("new_password")),
        el("label", {}, t("repeat_password") + " ", input("repeat_password")),
        el("button", { id: "change-password", onclick: change }, t("change_password")), el("p", {}, t("password-sealed")));
      return parts;
    },
  };

  // Pages of controls: not redrawn under a control being edited.
  const FORMS = ["settings", "network", "security", "firmware"];

  function current() {
    const name = location.hash.slice(1);
    return Object.hasOwn(PAGES, name) ? name : "status";
  }

  // `fresh` made the shape of `old` in place (text, attributes), so that a control keeps its
  // focus and a click its target; what differs in shape is replaced.
  function patch(old, fresh) {
    if (old.nodeName !== fresh.nodeName || old.childNodes.length !== fresh.childNodes.length) {
      old.replaceWith(fresh);
    } else if (old.nodeType === Node.TEXT_NODE) {
      if (old.data !== fresh.data) old.data = fresh.data;
    } else {
      for (const a of Array.from(old.attributes)) if (!fresh.hasAttribute(a.name)) old.removeAttribute(a.name);
      for (const a of Array.from(fresh.attributes)) if (old.getAttribute(a.name) !== a.value) old.setAttribute(a.name, a.value);
      const olds = Array.from(old.childNodes);
      Array.from(fresh.childNodes).forEach((c, i) => patch(olds[i], c));
    }
  }

  // Draws the current page, one drawing at a time (a call during one asks for another after
  // it); the live I/O page again about twice a second, less often while the module does not
  // answer (up to 10 s), not while the tab is hidden. `force`: redraw the settings page even
  // under a control being edited (after a write).
  let drawing = false, again = false, againForced = false, failures = 0;
  async function show(force) {
    if (drawing) {
      again = true;
      againForced = againForced || force === true;
      return;
    }
    drawing = true;
    clearTimeout(timer);
    const name = current();
    for (const a of document.querySelectorAll("nav a")) a.classList.toggle("on", a.getAttribute("href") === "#" + name);
    try {
      if (!identity) identity = await loadIdentity();
      const content = [await PAGES[name]()].flat();
      if (current() !== name) {
        // The page changed while this one loaded: drawn by the next call.
      } else if (name === "io" && page.dataset.shows === "io" && page.childNodes.length === content.length) {
        const olds = Array.from(page.childNodes);
        content.forEach((c, i) => patch(olds[i], c));
      } else if (page.dataset.shows !== name || !FORMS.includes(name) || force === true || !page.contains(document.activeElement)) {
        // A control being edited is not redrawn under the user's hands; another page's control
        // (a DO just clicked, say) never keeps this page from being drawn.
        page.replaceChildren(...content);
        page.dataset.shows = name;
      }
      failures = 0;
    } catch (e) {
      failures += 1;
      say(String(e.message || e), true);
    }
    drawing = false;
    if (again) {
      const forced = againForced;
      again = againForced = false;
      show(forced);
    } else if (current() === "io" && !document.hidden) {
      timer = setTimeout(show, Math.min(500 * 2 ** failures, 10000));
    }
  }

  async function loadIdentity() {
    const i = await get("identity");
    $("model").textContent = i.name;
    document.title = i.name;
    return i;
  }

  function translate() {
    document.documentElement.lang = lang === "zh" ? "zh-CN" : "en";
    for (const e of document.querySelectorAll("[data-t]")) e.textContent = t(e.dataset.t);
    $("lang").textContent = lang === "zh" ? "English" : "中文";
    $("login").textContent = t(session ? "logout" : "login");
  }

  $("lang").addEventListener("click", () => {
    lang = lang === "zh" ? "en" : "zh";
    localStorage.setItem("rdaq-lang", lang);
    translate();
    show();
  });

  $("login").addEventListener("click", async () => {
    if (session) {
      await signed("DELETE", "session").catch(() => {});
      session = null;
      say(t("logged out"));
      translate();
      show(true);
      return;
    }
    $("login-error").textContent = "";
    $("login-dialog").showModal();
  });

  $("login-form").addEventListener("submit", async (e) => {
    if (e.submitter && e.submitter.value === "cancel") return;
    e.preventDefault();
    try {
      await login($("password").value);
      $("password").value = "";
      $("login-dialog").close();
      say(t("logged in"));
      translate();
      show(true);
    } catch (err) {
      $("login-error").textContent = String(err.message || err);
    }
  });

  window.addEventListener("hashchange", () => show());
  document.addEventListener("visibilitychange", () => document.hidden || show());
  $("login-dialog").addEventListener("close", () => {
    $("password").value = "";
  });

  translate();
  show();
})();
