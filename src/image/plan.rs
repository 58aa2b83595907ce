//! What `jetpilot image install` puts into the root filesystem: every file with its
//! source, destination and mode, the enable symlinks, and the folders they need. Built
//! from validated inputs; nothing here touches the image.

use std::path::PathBuf;

/// The configs shipped in the binary, by kit name (installed in /etc/jetpilot).
pub const KITS: [(&str, &str); 4] = [
    ("jetbot", include_str!("../../config/jetbot.toml")),
    ("waveshare", include_str!("../../config/waveshare.toml")),
    ("yahboom", include_str!("../../config/yahboom.toml")),
    ("l298n-nano", include_str!("../../config/l298n-nano.toml")),
];

const UNIT: &str = include_str!("../../systemd/jetpilot.service");
const FIRSTBOOT_UNIT: &str = include_str!("../../systemd/jetpilot-firstboot.service");
const SYSUSERS: &str = include_str!("../../systemd/jetpilot.sysusers.conf");
const TMPFILES: &str = include_str!("../../systemd/jetpilot.tmpfiles.conf");
const UDEV_RULES: &str = include_str!("../../systemd/99-jetpilot.rules");
const CSI_CAMERA: &str = include_str!("../../systemd/csi-camera.conf");
const GPIO_MOTORS: &str = include_str!("../../systemd/gpio-motors.conf");

/// Where a file's bytes come from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Source {
    File(PathBuf),
    Bytes(Vec<u8>),
}

/// One file to install, owned by root.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FileItem {
    pub dest: String,
    pub source: Source,
    /// Permission bits, e.g. 0o644.
    pub mode: u32,
    pub size: u64,
}

/// A symlink `dest` -> `target`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LinkItem {
    pub dest: String,
    pub target: String,
}

/// Everything to write.
#[derive(Debug, Clone, Default)]
pub struct Plan {
    pub files: Vec<FileItem>,
    pub links: Vec<LinkItem>,
}

/// The validated inputs a plan is made from.
pub struct PlanInputs<'a> {
    pub binary: (PathBuf, u64),
    pub onnxruntime: (PathBuf, u64),
    pub model: (PathBuf, u64),
    /// Where the kit's config wants the model (its `model.path`).
    pub model_dest: String,
    /// The kit config's text, installed as /etc/jetpilot/jetpilot.toml.
    pub kit_config: &'a str,
    /// Whether the kit reads the CSI camera (the drop-in for nvargus) and drives GPIO
    /// motors (the drop-in for sysfs PWM).
    pub csi_camera: bool,
    pub gpio_motors: bool,
    /// A NetworkManager keyfile's text, if Wi-Fi credentials were given.
    pub wifi: Option<String>,
}

impl Plan {
    pub fn new(i: &PlanInputs<'_>) -> Self {
        let mut files = Vec::new();
        let mut file = |dest: &str, source: Source, mode: u32, size: u64| {
            files.push(FileItem {
                dest: dest.to_string(),
                source,
                mode,
                size,
            })
        };
        let text = |s: &str| (Source::Bytes(s.as_bytes().to_vec()), s.len() as u64);
        file(
            "/usr/bin/jetpilot",
            Source::File(i.binary.0.clone()),
            0o755,
            i.binary.1,
        );
        file(
            "/usr/lib/jetpilot/libonnxruntime.so.1.23.2",
            Source::File(i.onnxruntime.0.clone()),
            0o644,
            i.onnxruntime.1,
        );
        let (s, n) = text(i.kit_config);
        file("/etc/jetpilot/jetpilot.toml", s, 0o644, n);
        for (kit, cfg) in KITS {
            let (s, n) = text(cfg);
            file(&format!("/etc/jetpilot/{kit}.toml"), s, 0o644, n);
        }
        for (dest, body) in [
            ("/lib/systemd/system/jetpilot.service", UNIT),
            (
                "/lib/systemd/system/jetpilot-firstboot.service",
                FIRSTBOOT_UNIT,
            ),
            ("/usr/lib/sysusers.d/jetpilot.conf", SYSUSERS),
            ("/usr/lib/tmpfiles.d/jetpilot.conf", TMPFILES),
            ("/lib/udev/rules.d/99-jetpilot.rules", UDEV_RULES),
        ] {
            let (s, n) = text(body);
            file(dest, s, 0o644, n);
        }
        if i.csi_camera {
            let (s, n) = text(CSI_CAMERA);
            file(
                "/etc/systemd/system/jetpilot.service.d/csi-camera.conf",
                s,
                0o644,
                n,
            );
        }
        if i.gpio_motors {
            let (s, n) = text(GPIO_MOTORS);
            file(
                "/etc/systemd/system/jetpilot.service.d/gpio-motors.conf",
                s,
                0o644,
                n,
            );
        }
        file(
            &i.model_dest,
            Source::File(i.model.0.clone()),
            0o644,
            i.model.1,
        );
        if let Some(w) = &i.wifi {
            let (s, n) = text(w);
            file(
                "/etc/NetworkManager/system-connections/jetpilot-wifi.nmconnection",
                s,
                0o600,
                n,
            );
        }
        let links = vec![
            LinkItem {
                dest: "/etc/systemd/system/multi-user.target.wants/jetpilot.service".into(),
                target: "/lib/systemd/system/jetpilot.service".into(),
            },
            LinkItem {
                dest: "/etc/systemd/system/sysinit.target.wants/jetpilot-firstboot.service".into(),
                target: "/lib/systemd/system/jetpilot-firstboot.service".into(),
            },
        ];
        Self { files, links }
    }

    /// Every folder the files and links need, with all their ancestors, parents first.
    pub fn dirs(&self) -> Vec<String> {
        let mut dirs = std::collections::BTreeSet::new();
        dirs.insert("/".to_string());
        let paths = self
            .files
            .iter()
            .map(|f| &f.dest)
            .chain(self.links.iter().map(|l| &l.dest));
        for p in paths {
            let mut at = 0;
            while let Some(i) = p[at + 1..].find('/') {
                at += i + 1;
                dirs.insert(p[..at].to_string());
            }
        }
        let mut v: Vec<String> = dirs.into_iter().collect();
        v.sort_by_key(|d| (d.matches('/').count(), d.clone()));
        v
    }
}

/// A NetworkManager keyfile for a WPA-PSK network. The UUID is derived from the SSID, so
/// installing twice writes the same file.
pub fn wifi_keyfile(ssid: &str, psk: &str) -> Result<String, String> {
    if ssid.is_empty() || ssid.len() > 32 || ssid.contains(['\n', '\r']) {
        return Err(format!("Wi-Fi SSID {ssid:?}: 1 to 32 bytes, one line"));
    }
    if !(8..=63).contains(&psk.len()) || psk.contains(['\n', '\r']) {
        return Err("Wi-Fi password: WPA needs 8 to 63 characters on one line".into());
    }
    if ssid.contains(';') || ssid.trim() != ssid {
        return Err(format!(
            "Wi-Fi SSID {ssid:?}: a `;` or spaces at either end are not supported here; \
             add the network with nmcli on the robot instead"
        ));
    }
    // NetworkManager's keyfiles are GLib key files: `\` escapes, a leading space is `\s`.
    let escape = |v: &str| {
        let e = v.replace('\\', "\\\\");
        match e.strip_prefix(' ') {
            Some(rest) => format!("\\s{rest}"),
            None => e,
        }
    };
    let (ssid_v, psk_v) = (escape(ssid), escape(psk));
    let h = crc32fast::hash(ssid.as_bytes());
    let g = crc32fast::hash(format!("jetpilot-wifi:{ssid}").as_bytes());
    let uuid = format!(
        "{:08x}-{:04x}-4{:03x}-a{:03x}-{:08x}{:04x}",
        h,
        g >> 16,
        g & 0xfff,
        (h >> 4) & 0xfff,
        g,
        h & 0xffff
    );
    Ok(format!(
        "[connection]\nid=jetpilot-wifi\nuuid={uuid}\ntype=wifi\nautoconnect=true\n\n\
         [wifi]\nmode=infrastructure\nssid={ssid_v}\n\n\
         [wifi-security]\nkey-mgmt=wpa-psk\npsk={psk_v}\n\n\
         [ipv4]\nmethod=auto\n\n[ipv6]\nmethod=auto\n"
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn inputs(kit: &str) -> PlanInputs<'_> {
        PlanInputs {
            binary: ("jetpilot".into(), 10),
            onnxruntime: ("ort.so".into(), 20),
            model: ("m.onnx".into(), 30),
            model_dest: "/var/lib/jetpilot/model.onnx".into(),
            kit_config: kit,
            csi_camera: true,
            gpio_motors: false,
            wifi: None,
        }
    }

    #[test]
    fn the_plan_installs_the_daemon_its_runtime_configs_units_and_model() {
        let p = Plan::new(&inputs("x"));
        let dests: Vec<&str> = p.files.iter().map(|f| f.dest.as_str()).collect();
        for d in [
            "/usr/bin/jetpilot",
            "/usr/lib/jetpilot/libonnxruntime.so.1.23.2",
            "/etc/jetpilot/jetpilot.toml",
            "/etc/jetpilot/l298n-nano.toml",
            "/lib/systemd/system/jetpilot.service",
            "/etc/systemd/system/jetpilot.service.d/csi-camera.conf",
            "/var/lib/jetpilot/model.onnx",
        ] {
            assert!(dests.contains(&d), "{d}");
        }
        assert!(!dests.iter().any(|d| d.contains("gpio-motors")));
        assert_eq!(p.files[0].mode, 0o755);
        let dirs = p.dirs();
        assert_eq!(dirs[0], "/");
        let i = |d: &str| dirs.iter().position(|x| x == d).unwrap();
        assert!(i("/etc/systemd") < i("/etc/systemd/system/multi-user.target.wants"));
    }

    #[test]
    fn wifi_keyfiles_are_checked_and_stable() {
        let a = wifi_keyfile("robots", "secret123").unwrap();
        assert_eq!(a, wifi_keyfile("robots", "secret123").unwrap());
        assert!(a.contains("ssid=robots\n") && a.contains("psk=secret123\n"));
        assert!(wifi_keyfile("robots", "short").is_err());
        assert!(wifi_keyfile("", "secret123").is_err());
        assert!(wifi_keyfile("a;b", "secret123").is_err());
        let k = wifi_keyfile("robots", r" back\slash").unwrap();
        assert!(k.contains(r"psk=\sback\\slash"), "{k}");
    }
}
