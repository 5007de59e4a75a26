//! A real MQTT broker for the uplink's tests: Debian's Mosquitto, started
//! by the test itself on a free loopback port with a config file of its
//! own (never the system's service), and [`Mqtt`], a plain MQTT 5 client
//! (rumqttc's `v5`) that can also send what lluav's clients never would.
//!
//! [`Mosquitto::recommended`] runs the README's broker config and ACL as
//! written there (only its paths and port replaced), so that what the
//! README recommends is what the tests prove.
//!
//! `scripts/test-uplink.sh` installs Mosquitto when it is missing;
//! `MOSQUITTO=path` picks another binary.

use std::io::Read;
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use rumqttc::Outgoing;
pub use rumqttc::v5::MqttOptions;
pub use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::mqttbytes::v5::{Filter, Packet};
pub use rumqttc::v5::mqttbytes::v5::{Publish, PublishProperties};
use rumqttc::v5::{AsyncClient, Event};
use serde_json::Value;
use tokio::sync::{mpsc, watch};

use crate::{Lluavd, Options, WAIT, test_ca};

/// The Mosquitto binary.
fn mosquitto_bin() -> PathBuf {
    if let Some(path) = std::env::var_os("MOSQUITTO") {
        return path.into();
    }
    for candidate in [
        "/usr/sbin/mosquitto",
        "/usr/bin/mosquitto",
        "/usr/local/sbin/mosquitto",
    ] {
        if Path::new(candidate).exists() {
            return candidate.into();
        }
    }
    panic!("Mosquitto is not installed: run `bash scripts/test-uplink.sh`, which installs it")
}

/// A free TCP port on loopback (free when asked; the broker binds it next).
pub fn free_port() -> u16 {
    let listener = TcpListener::bind("127.0.0.1:0").expect("a free port");
    listener.local_addr().expect("local address").port()
}

/// How a broker listens and whom it lets in.
#[derive(Clone, Debug, Default)]
pub struct BrokerOptions {
    /// Serve `mqtts://` with a certificate from [`test_ca`].
    pub tls: bool,
    /// Only these users (name, password), through a password file.
    pub users: Vec<(String, String)>,
    /// Further lines of the config file (a bridge, limits, an ACL).
    pub extra: String,
    /// Run the README's broker config (`lluav.conf`) and ACL instead of
    /// the plain one: `users` are its accounts, and each one without a
    /// block in the README's ACL gets one made from the README's block of
    /// its kind (an operator's from `alice`'s, a vehicle's from
    /// `drone-1`'s; a user named `drone-*` is a vehicle).
    pub recommended: bool,
}

/// The README's fenced block whose first line is `first`.
pub fn readme_block(first: &str) -> String {
    let readme =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../README.md")).expect("README");
    let opening = format!("```text\n{first}");
    let start = readme
        .find(&opening)
        .unwrap_or_else(|| panic!("no README block starting {first:?}"));
    let block = &readme[start + "```text\n".len()..];
    block[..block.find("```").expect("its end")].to_owned()
}

/// The README's ACL, with a block for each of `users` it does not have.
pub fn readme_acl(users: &[(String, String)]) -> String {
    let mut acl = readme_block("# /etc/mosquitto/lluav.acl");
    let block = |name: &str| -> String {
        let from = acl.find(&format!("\nuser {name}\n")).expect("the README's block") + 1;
        let rest = &acl[from..];
        rest[..rest.find("\n\n").unwrap_or(rest.len())].to_owned()
    };
    let (operator, vehicle) = (block("alice"), block("drone-1"));
    for (user, _) in users {
        if acl.contains(&format!("\nuser {user}\n")) {
            continue;
        }
        let made = if user.starts_with("drone-") {
            vehicle.replace("drone-1", user)
        } else {
            operator.replace("alice", user)
        };
        acl.push_str(&format!("\n{made}\n"));
    }
    acl
}

/// A running Mosquitto, stopped on drop.
pub struct Mosquitto {
    child: Option<Child>,
    /// Its port on 127.0.0.1.
    pub port: u16,
    /// `mqtt://127.0.0.1:PORT`, or `mqtts://localhost:PORT`.
    pub url: String,
    /// Whether it serves `mqtts://` (with a certificate of [`test_ca`]).
    pub tls: bool,
    dir: tempfile::TempDir,
}

impl Mosquitto {
    /// A plain broker that lets anyone in.
    pub fn start() -> Mosquitto {
        Mosquitto::with(&BrokerOptions::default())
    }

    /// A broker as `options` say.
    pub fn with(options: &BrokerOptions) -> Mosquitto {
        let dir = tempfile::tempdir().expect("temp dir");
        let port = free_port();
        let mut config = "persistence false\nlog_dest stderr\n\
             # Run as whoever started the test (root in CI), never as another user.\nuser root\n"
            .to_owned();
        let passwords = dir.path().join("passwords");
        if !options.users.is_empty() {
            std::fs::write(&passwords, "").expect("password file");
            for (user, password) in &options.users {
                let status = Command::new("mosquitto_passwd")
                    .arg("-b")
                    .arg(&passwords)
                    .args([user, password])
                    .status()
                    .expect("mosquitto_passwd runs");
                assert!(status.success(), "mosquitto_passwd failed");
            }
        }
        let tls = options.tls || options.recommended;
        let (cert, key) = if tls {
            test_ca().issue(dir.path())
        } else {
            Default::default()
        };
        if options.recommended {
            let acl = dir.path().join("lluav.acl");
            std::fs::write(&acl, readme_acl(&options.users)).expect("ACL written");
            for line in readme_block("# /etc/mosquitto/conf.d/lluav.conf").lines() {
                let (key_word, _) = line.split_once(' ').unwrap_or((line, ""));
                let line = match key_word {
                    "listener" => format!("listener {port} 127.0.0.1"),
                    "certfile" => format!("certfile {}", cert.display()),
                    "keyfile" => format!("keyfile {}", key.display()),
                    "password_file" => format!("password_file {}", passwords.display()),
                    "acl_file" => format!("acl_file {}", acl.display()),
                    _ => line.to_owned(),
                };
                config.push_str(&line);
                config.push('\n');
            }
        } else {
            config.push_str(&format!("listener {port} 127.0.0.1\nset_tcp_nodelay true\n"));
            if tls {
                config.push_str(&format!(
                    "certfile {}\nkeyfile {}\n",
                    cert.display(),
                    key.display()
                ));
            }
            if options.users.is_empty() {
                config.push_str("allow_anonymous true\n");
            } else {
                config.push_str(&format!(
                    "allow_anonymous false\npassword_file {}\n",
                    passwords.display()
                ));
            }
        }
        config.push_str(&options.extra);
        std::fs::write(dir.path().join("mosquitto.conf"), config).expect("config written");
        let scheme = if tls {
            "mqtts://localhost"
        } else {
            "mqtt://127.0.0.1"
        };
        let mut broker = Mosquitto {
            child: None,
            port,
            url: format!("{scheme}:{port}"),
            tls,
            dir,
        };
        broker.run();
        broker
    }

    /// The README's broker (TLS, accounts, the ACL) with `users`.
    pub fn recommended(users: &[(&str, &str)]) -> Mosquitto {
        Mosquitto::with(&BrokerOptions {
            users: users
                .iter()
                .map(|(u, p)| ((*u).to_owned(), (*p).to_owned()))
                .collect(),
            recommended: true,
            ..BrokerOptions::default()
        })
    }

    /// Starts the broker (again, on the same port) and waits until it
    /// accepts connections.
    pub fn run(&mut self) {
        let log = std::fs::File::options()
            .create(true)
            .append(true)
            .open(self.dir.path().join("mosquitto.log"))
            .expect("log file");
        let child = Command::new(mosquitto_bin())
            .arg("-c")
            .arg(self.dir.path().join("mosquitto.conf"))
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .expect("mosquitto starts");
        self.child = Some(child);
        let start = Instant::now();
        while std::net::TcpStream::connect(("127.0.0.1", self.port)).is_err() {
            assert!(
                start.elapsed() < WAIT,
                "mosquitto did not listen:\n{}",
                self.log()
            );
            if let Some(Ok(Some(status))) = self.child.as_mut().map(Child::try_wait) {
                panic!("mosquitto exited with {status}:\n{}", self.log());
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Stops the broker (SIGTERM) and waits for it.
    pub fn stop(&mut self) {
        if let Some(mut child) = self.child.take() {
            signal(child.id(), "TERM");
            let _ = child.wait();
        }
    }

    /// Freezes (`STOP`) or thaws (`CONT`) the broker: its connections stay
    /// open, nothing moves.
    pub fn signal(&self, name: &str) {
        if let Some(child) = &self.child {
            signal(child.id(), name);
        }
    }

    /// The broker's process id.
    pub fn pid(&self) -> Option<u32> {
        self.child.as_ref().map(Child::id)
    }

    /// What the broker logged.
    pub fn log(&self) -> String {
        let mut text = String::new();
        if let Ok(mut f) = std::fs::File::open(self.dir.path().join("mosquitto.log")) {
            let _ = f.read_to_string(&mut text);
        }
        text
    }

    /// A bridge from this broker to `remote`: everything under `lluav/`
    /// both ways (config lines for [`BrokerOptions::extra`]).
    pub fn bridge_to(remote: &Mosquitto) -> String {
        format!(
            "connection to-{port}\naddress 127.0.0.1:{port}\ntopic lluav/# both 1\n\
             cleansession true\nrestart_timeout 1\n",
            port = remote.port
        )
    }
}

impl Drop for Mosquitto {
    fn drop(&mut self) {
        if let Some(child) = &self.child {
            signal(child.id(), "CONT");
        }
        self.stop();
    }
}

fn signal(pid: u32, name: &str) {
    let _ = Command::new("kill")
        .arg(format!("-{name}"))
        .arg(pid.to_string())
        .status();
}

/// The admin login value the tests' vehicles are given: with an uplink,
/// lluavd refuses the public `1025` unless told otherwise.
pub const ADMIN: &str = "adm-4711";

/// `options` with the tests' admin value in a config file in the data
/// directory `dir` (unless `options` bring a config file or allow the
/// public value).
pub fn with_admin(dir: &Path, options: Options) -> Options {
    let told = options
        .args
        .iter()
        .any(|a| a == "--config" || a == "--allow-default-admin");
    if told {
        return options;
    }
    std::fs::create_dir_all(dir).expect("data dir");
    let config = dir.join("lluavd-test.toml");
    std::fs::write(&config, format!("admin_password = \"{ADMIN}\"\n")).expect("config written");
    options.with_args(&["--config", config.to_str().expect("UTF-8 path")])
}

/// `options` for a vehicle on `broker`: [`with_admin`], the broker's URL
/// and, for `mqtts://`, the test CA.
pub fn vehicle_options(dir: &Path, broker: &Mosquitto, options: Options) -> Options {
    let mut options = with_admin(dir, options).with_args(&["--uplink", &broker.url]);
    if broker.tls {
        let ca = test_ca().ca_file();
        options = options.with_args(&["--uplink-cafile", ca.to_str().expect("UTF-8 path")]);
    }
    options
}

/// `lluavd --uplink URL --vehicle-id ID` with `options` (see
/// [`vehicle_options`]), started and online (its retained status says so;
/// watched anonymously).
pub async fn vehicle(dir: &Path, broker: &Mosquitto, id: &str, options: Options) -> Lluavd {
    let options = vehicle_options(dir, broker, options).with_args(&["--vehicle-id", id]);
    let since = unix_ms();
    let daemon = Lluavd::start(dir, &options);
    let watch = Mqtt::connect(broker, &format!("watch-{id}")).await;
    online(watch, id, since, &daemon).await;
    daemon
}

/// Milliseconds since 1970.
fn unix_ms() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX))
}

/// Waits until `watch` sees vehicle `id`'s status say it is online, in a
/// status sent at `since` (Unix ms) or later: a vehicle started again is
/// not online until its new run says so.
pub async fn online(mut watch: Mqtt, id: &str, since: i64, daemon: &Lluavd) {
    watch.subscribe(&format!("lluav/{id}/status")).await;
    let start = Instant::now();
    loop {
        let status = watch.json().await;
        if status.1["online"] == true && status.1["ts"].as_i64().is_some_and(|ts| ts >= since) {
            break;
        }
        assert!(
            start.elapsed() < WAIT,
            "{id} never came online:\n{}",
            daemon.stderr()
        );
    }
    watch.close().await;
}

/// A plain MQTT 5 client.
pub struct Mqtt {
    client: AsyncClient,
    messages: mpsc::UnboundedReceiver<Publish>,
    acks: mpsc::UnboundedReceiver<bool>,
    /// How many of this client's publishes the broker has taken: QoS 0
    /// ones once written, QoS 1 once acknowledged, QoS 2 once completed.
    settled: watch::Receiver<u64>,
    /// How many publishes were handed to the client.
    published: std::sync::atomic::AtomicU64,
    /// Set when the connection ends.
    closed: watch::Receiver<bool>,
    task: tokio::task::JoinHandle<()>,
}

impl Mqtt {
    /// Options to connect to `broker` as `client_id` (trusting the test CA
    /// for `mqtts://`), taking messages up to 1 MiB.
    pub fn options(broker: &Mosquitto, client_id: &str) -> MqttOptions {
        let mut options = MqttOptions::new(client_id, "127.0.0.1", broker.port);
        options.set_max_packet_size(Some(1 << 20));
        // Without it, Nagle's algorithm and delayed ACKs add about 40 ms to
        // every round trip.
        let mut network = rumqttc::NetworkOptions::new();
        network.set_tcp_nodelay(true);
        options.set_network_options(network);
        if broker.tls {
            let config = lluav_host::client::tls_config(Some(&test_ca().ca_file())).expect("the test CA");
            options.set_transport(rumqttc::Transport::tls_with_config(
                rumqttc::TlsConfiguration::Rustls(std::sync::Arc::new(config)),
            ));
        }
        options
    }

    /// Connects to `broker` as `client_id`, anonymously.
    pub async fn connect(broker: &Mosquitto, client_id: &str) -> Mqtt {
        Mqtt::with(Mqtt::options(broker, client_id))
            .await
            .unwrap_or_else(|e| panic!("cannot connect: {e}"))
    }

    /// Connects to `broker` as `user` (client id `client_id`), or says why
    /// not.
    pub async fn login(
        broker: &Mosquitto,
        client_id: &str,
        user: &str,
        password: &str,
    ) -> Result<Mqtt, String> {
        let mut options = Mqtt::options(broker, client_id);
        options.set_credentials(user, password);
        Mqtt::with(options).await
    }

    /// Connects with `options`, or says why not.
    pub async fn with(options: MqttOptions) -> Result<Mqtt, String> {
        let (client, mut events) = AsyncClient::new(options, 10_000);
        match tokio::time::timeout(WAIT, events.poll()).await {
            Ok(Ok(Event::Incoming(Packet::ConnAck(_)))) => {}
            other => return Err(format!("{other:?}")),
        }
        let (tx, messages) = mpsc::unbounded_channel();
        let (ack_tx, acks) = mpsc::unbounded_channel();
        let (settled_tx, settled) = watch::channel(0u64);
        let (closed_tx, closed) = watch::channel(false);
        let task = tokio::spawn(async move {
            loop {
                match events.poll().await {
                    Ok(Event::Incoming(Packet::Publish(p))) => {
                        let _ = tx.send(p);
                    }
                    Ok(Event::Incoming(Packet::SubAck(ack))) => {
                        let granted = ack.return_codes.iter().all(|c| {
                            matches!(c, rumqttc::v5::mqttbytes::v5::SubscribeReasonCode::Success(_))
                        });
                        let _ = ack_tx.send(granted);
                    }
                    Ok(
                        Event::Outgoing(Outgoing::Publish(0))
                        | Event::Incoming(Packet::PubAck(_) | Packet::PubComp(_)),
                    ) => settled_tx.send_modify(|n| *n += 1),
                    Ok(_) => {}
                    Err(_) => {
                        let _ = closed_tx.send(true);
                        return;
                    }
                }
            }
        });
        Ok(Mqtt {
            client,
            messages,
            acks,
            settled,
            published: std::sync::atomic::AtomicU64::new(0),
            closed,
            task,
        })
    }

    /// Subscribes to `filter` and waits until the broker granted it.
    pub async fn subscribe(&mut self, filter: &str) {
        assert!(
            self.try_subscribe(filter).await,
            "subscription to {filter} refused"
        );
    }

    /// Subscribes to `filter`: whether the broker granted it.
    pub async fn try_subscribe(&mut self, filter: &str) -> bool {
        self.client
            .subscribe_many([Filter::new(filter, QoS::AtLeastOnce)])
            .await
            .expect("subscribe queued");
        tokio::time::timeout(WAIT, self.acks.recv())
            .await
            .expect("subscription answered in time")
            .expect("the connection is open")
    }

    /// Publishes `payload` on `topic` and returns once the broker has it
    /// (acknowledged at QoS 1 and 2, written at QoS 0). rumqttc's
    /// `publish` only queues: a test that starts a vehicle next would
    /// otherwise race the client's event loop, which cannot run while the
    /// test's runtime is blocked starting the daemon.
    pub async fn publish(&self, topic: &str, payload: impl Into<Vec<u8>>, qos: QoS, retain: bool) {
        self.publish_with(topic, payload, qos, retain, None).await;
    }

    /// [`Mqtt::publish`] with MQTT 5 properties (Message Expiry, ...).
    pub async fn publish_with(
        &self,
        topic: &str,
        payload: impl Into<Vec<u8>>,
        qos: QoS,
        retain: bool,
        properties: Option<PublishProperties>,
    ) {
        let payload = payload.into();
        let queued = match properties {
            Some(p) => {
                self.client
                    .publish_with_properties(topic, qos, retain, payload, p)
                    .await
            }
            None => self.client.publish(topic, qos, retain, payload).await,
        };
        queued.expect("publish queued");
        let mine = self.published.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
        let mut settled = self.settled.clone();
        tokio::time::timeout(WAIT, settled.wait_for(|n| *n >= mine))
            .await
            .expect("the broker took the message in time")
            .expect("the connection is open");
    }

    /// The next message.
    pub async fn next(&mut self) -> Publish {
        tokio::time::timeout(WAIT, self.messages.recv())
            .await
            .expect("a message in time")
            .expect("the connection is open")
    }

    /// The next message within `limit`, if any.
    pub async fn next_within(&mut self, limit: Duration) -> Option<Publish> {
        tokio::time::timeout(limit, self.messages.recv())
            .await
            .ok()
            .flatten()
    }

    /// The next message as (topic, JSON).
    pub async fn json(&mut self) -> (String, Value) {
        let p = self.next().await;
        let value = serde_json::from_slice(&p.payload)
            .unwrap_or_else(|e| panic!("not JSON ({e}): {:?}", String::from_utf8_lossy(&p.payload)));
        (topic(&p), value)
    }

    /// Sends `{"id": id, "frame": frame}` to vehicle `vehicle` as client
    /// `client` and returns the answer envelope with that id (the client
    /// must be subscribed to `lluav/+/res/<client>`).
    pub async fn request(&mut self, vehicle: &str, client: &str, id: &str, frame: &str) -> Value {
        let envelope = serde_json::json!({"id": id, "frame": frame}).to_string();
        self.publish(
            &format!("lluav/{vehicle}/req/{client}"),
            envelope,
            QoS::AtLeastOnce,
            false,
        )
        .await;
        self.answer(id).await
    }

    /// The answer envelope whose id is `id`, skipping others.
    pub async fn answer(&mut self, id: &str) -> Value {
        loop {
            let (topic, value) = self.json().await;
            if topic.contains("/res/") && value["id"] == id {
                return value;
            }
        }
    }

    /// Waits until the broker ends this connection (another client took
    /// its client id, say); false if it did not within `limit`.
    pub async fn closed_within(&self, limit: Duration) -> bool {
        let mut closed = self.closed.clone();
        tokio::time::timeout(limit, closed.wait_for(|c| *c)).await.is_ok()
    }

    /// Whether the connection is still open.
    pub fn is_open(&self) -> bool {
        !*self.closed.borrow()
    }

    /// Disconnects.
    pub async fn close(self) {
        let _ = self.client.disconnect().await;
        let _ = tokio::time::timeout(Duration::from_secs(2), self.task).await;
    }
}

/// The topic of a message.
pub fn topic(p: &Publish) -> String {
    String::from_utf8_lossy(&p.topic).into_owned()
}
