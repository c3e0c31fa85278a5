//! English and Simplified Chinese (the manuals exist in both). Texts are written in English in
//! the code; [`Lang::t`] gives the Chinese of those in [`ZH`], and the English text itself for
//! the rest (numbers, names, labels the tests query).

use crate::validate::Problem;

/// The language of the window.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Lang {
    #[default]
    En,
    Zh,
}

impl Lang {
    /// `en` in this language.
    pub fn t(self, en: &'static str) -> &'static str {
        match self {
            Lang::En => en,
            Lang::Zh => ZH.iter().find(|(e, _)| *e == en).map_or(en, |(_, z)| z),
        }
    }
}

/// The English text of a field problem.
pub fn problem(p: Problem) -> &'static str {
    match p {
        Problem::NotAnAddress => "Not an IPv4 address (four numbers 0-255)",
        Problem::NotUnicast => "Not a unicast address",
        Problem::HostPartAllZerosOrOnes => "The subnet's network or broadcast address",
        Problem::MaskNotContiguous => "The mask's ones are not contiguous",
        Problem::MaskSize => "The mask leaves no room for hosts (/1 to /30)",
        Problem::GatewayOutsideSubnet => "The gateway is not in the subnet",
        Problem::GatewayIsModule => "The gateway is the module's own address",
        Problem::Port => "The port is 1 to 65535",
    }
}

/// The Chinese texts (as the Chinese manuals name things where they do).
pub static ZH: &[(&str, &str)] = &[
    ("File", "文件"),
    ("Tool", "工具"),
    ("Help", "帮助"),
    ("Export trend to CSV", "导出趋势为 CSV"),
    ("Exit", "退出"),
    ("Search", "搜索"),
    ("Search the LAN", "在局域网中搜索"),
    ("Searching…", "搜索中…"),
    ("Search the LAN for modules", "在局域网中搜索模块"),
    ("Language", "语言"),
    ("Interface", "网卡"),
    ("All interfaces", "所有网卡"),
    ("Modules: RemoDAQ-8318, RemoDAQ-8350", "模块：RemoDAQ-8318、RemoDAQ-8350"),
    ("Ready", "就绪"),
    ("Modules found", "找到的模块"),
    ("The search failed", "搜索失败"),
    ("No module answered", "没有模块应答"),
    ("Press Search", "请点击搜索"),
    ("no answer", "无应答"),
    ("Modbus exception", "Modbus 异常"),
    ("refused", "被拒绝"),
    ("bad reply", "应答错误"),
    ("error", "错误"),
    ("Host Information", "主机信息"),
    ("IP address", "IP 地址"),
    ("Recent host IPs", "最近的主机 IP"),
    ("Network Settings", "网络设置"),
    ("Trends", "趋势"),
    ("Diagnostics", "诊断"),
    ("Security", "安全"),
    ("Firmware", "固件"),
    ("Subnet mask", "子网掩码"),
    ("Gateway", "网关"),
    ("Remote port", "远程端口"),
    ("Setting", "设置"),
    ("ReStart", "重启"),
    ("In force", "当前生效"),
    ("Stored (after a restart)", "已保存（重启后生效）"),
    ("gateway", "网关"),
    ("port", "端口"),
    ("none", "无"),
    ("firmware", "固件"),
    ("up", "运行"),
    (
        "The factory password is in force: anyone on the LAN can change these settings. Set one in Security.",
        "仍为出厂密码：局域网中任何人都能修改这些设置。请在“安全”中设置密码。",
    ),
    ("Configuration password", "配置密码"),
    ("Password", "密码"),
    ("OK", "确定"),
    ("Cancel", "取消"),
    ("Restarting; searching again…", "正在重启，稍后重新搜索…"),
    ("Restarted; in force", "已重启，当前生效"),
    ("The module did not answer a search after its restart", "模块重启后未应答搜索"),
    ("Reading…", "读取中…"),
    ("Input range", "输入范围"),
    ("Channel", "通道"),
    ("Value", "数值"),
    ("Status", "状态"),
    ("ok", "正常"),
    ("open", "断线"),
    ("over range", "超上限"),
    ("under range", "超下限"),
    ("disabled", "未启用"),
    ("front-end fault", "前端故障"),
    ("cold-junction fault", "冷端故障"),
    ("unknown", "未知"),
    ("CJC temperature", "冷端温度"),
    ("CJC offset (°C)", "冷端补偿偏移 (°C)"),
    ("Set offset", "设置偏移"),
    ("The CJC offset is -50.00 to 50.00 °C", "冷端偏移范围为 -50.00 至 50.00 °C"),
    ("Open input reads", "断线时读数"),
    ("FFFFh (upscale)", "FFFFh（上限）"),
    ("0000h (downscale)", "0000h（下限）"),
    ("Set all channels to", "所有通道设为"),
    ("Set all", "全部设置"),
    ("Normal", "普通"),
    ("Counter", "计数"),
    ("Latch L-H", "锁存 L-H"),
    ("Latch H-L", "锁存 H-L"),
    ("Frequency", "频率"),
    ("Mode", "模式"),
    ("Counter / frequency", "计数 / 频率"),
    ("Latch", "锁存"),
    ("running", "运行"),
    ("stopped", "停止"),
    ("Low (ms)", "低电平 (ms)"),
    ("High (ms)", "高电平 (ms)"),
    ("Count", "脉冲数"),
    ("Extra", "追加"),
    ("Pulse widths are 0.1 ms or more; counts are whole numbers", "脉宽至少 0.1 ms，脉冲数为整数"),
    ("Host watchdog", "主机看门狗"),
    ("Timeout", "超时"),
    ("off", "关闭"),
    ("Safe levels", "安全电平"),
    ("Power-on levels", "上电电平"),
    ("TRIPPED: outputs held at safe levels", "已触发：输出保持安全电平"),
    ("Watchdog timeout (s, 0 = off)", "看门狗超时（秒，0 = 关闭）"),
    ("Set watchdog", "设置看门狗"),
    ("Clear trip", "清除触发"),
    ("The watchdog timeout is 0.1 to 600 s, or 0 for off", "看门狗超时为 0.1 至 600 秒，或 0 关闭"),
    ("Resume", "继续"),
    ("Pause", "暂停"),
    ("Span", "时间跨度"),
    ("CSV file", "CSV 文件"),
    ("Export CSV", "导出 CSV"),
    ("time (s)", "时间 (s)"),
    ("Trend written to", "趋势已写入"),
    ("Cannot write", "无法写入"),
    ("Module status", "模块状态"),
    ("Uptime", "运行时间"),
    ("Reset cause", "复位原因"),
    ("Connections", "连接数"),
    ("Requests", "请求数"),
    ("Exceptions", "异常数"),
    ("Failed authentications", "认证失败次数"),
    ("Last failed source", "最近失败来源"),
    ("Refused by the guessing budget", "因猜测限制被拒"),
    ("Writes refused by the allow-list", "被白名单拒绝的写入"),
    ("Updates refused", "被拒绝的更新"),
    ("New password", "新密码"),
    ("New password again", "再次输入新密码"),
    ("At least 8 characters", "至少 8 个字符"),
    ("The two new passwords differ", "两次输入的新密码不同"),
    ("Change password", "修改密码"),
    ("Modbus write allow-list", "Modbus 写入白名单"),
    (
        "Up to 4 networks (192.168.0.0/24, 10.0.0.5); empty: any client may write",
        "最多 4 个网段（192.168.0.0/24、10.0.0.5）；为空：任何客户端都可写入",
    ),
    ("Allowed networks", "允许的网段"),
    ("Read list", "读取列表"),
    ("Store list", "保存列表"),
    ("At most 4 networks", "最多 4 个网段"),
    ("Modbus writes allowed from any client", "允许任何客户端写入 Modbus"),
    ("Modbus writes allowed only from", "仅允许以下网段写入 Modbus"),
    ("Firmware version", "固件版本"),
    ("Update key", "更新密钥"),
    ("Image file", "映像文件"),
    ("Update", "更新"),
    ("The image is for a", "该映像适用于"),
    ("verifying, then restarting…", "校验中，随后重启…"),
    ("Not an IPv4 address (four numbers 0-255)", "不是 IPv4 地址（四个 0-255 的数）"),
    ("Not a unicast address", "不是单播地址"),
    ("The subnet's network or broadcast address", "是子网的网络地址或广播地址"),
    ("The mask's ones are not contiguous", "掩码的 1 不连续"),
    ("The mask leaves no room for hosts (/1 to /30)", "掩码没有主机空间（/1 至 /30）"),
    ("The gateway is not in the subnet", "网关不在子网内"),
    ("The gateway is the module's own address", "网关是模块自身的地址"),
    ("The port is 1 to 65535", "端口为 1 至 65535"),
    (
        "Through the module's web console; not while the factory password is in force",
        "通过模块的网页控制台；出厂密码有效时不可更改",
    ),
    ("Web console", "网页控制台"),
    ("Time server (SNTP)", "时间服务器 (SNTP)"),
    ("Port", "端口"),
    ("Publish to the broker", "发布到代理服务器"),
    ("Broker address", "代理服务器地址"),
    ("Broker host name", "代理服务器主机名"),
    ("Client id", "客户端 ID"),
    ("Topic prefix", "主题前缀"),
    ("Period (ms)", "周期 (ms)"),
    ("QoS 1 (at least once)", "QoS 1（至少一次）"),
    ("Deadbands", "死区"),
    ("Publish on change", "变化时发布"),
    ("Take output commands", "接受输出命令"),
    ("stored", "已存储"),
    ("CA certificate", "CA 证书"),
    ("Broker credentials", "代理服务器凭据"),
    ("CA certificate file", "CA 证书文件"),
    ("Broker user", "代理服务器用户名"),
    ("Broker password", "代理服务器密码"),
    ("Read MQTT settings", "读取 MQTT 设置"),
    ("Store MQTT settings", "保存 MQTT 设置"),
    ("Not stored", "未保存"),
    ("MQTT settings as the module holds them", "模块中的 MQTT 设置"),
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_english_text_once_and_every_problem_translated() {
        for (i, (en, _)) in ZH.iter().enumerate() {
            assert!(!ZH[..i].iter().any(|(e, _)| e == en), "{en} twice");
        }
        for p in [
            Problem::NotAnAddress,
            Problem::NotUnicast,
            Problem::HostPartAllZerosOrOnes,
            Problem::MaskNotContiguous,
            Problem::MaskSize,
            Problem::GatewayOutsideSubnet,
            Problem::GatewayIsModule,
            Problem::Port,
        ] {
            assert_ne!(Lang::Zh.t(problem(p)), problem(p), "{p:?}");
        }
        assert_eq!(Lang::En.t("Search"), "Search");
        assert_eq!(Lang::Zh.t("Network Settings"), "网络设置");
    }
}
