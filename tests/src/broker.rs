//! A real MQTT broker for the uplink's tests: Debian's Mosquitto, started
//! by the test itself on a free loopback port with a config file of its
//! own (never the system's service), and [`Mqtt`], a plain rumqttc client
//! that can also send what lluav's clients never would.
//!
//! `scripts/test-uplink.sh` installs Mosquitto when it is missing;
//! `MOSQUITTO=path` picks another binary.

use std::io::Read;
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use rumqttc::{AsyncClient, Event, MqttOptions, Outgoing, Packet, Publish, QoS};
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
    /// Further lines of the config file (a bridge, limits).
    pub extra: String,
}

/// A running Mosquitto, stopped on drop.
pub struct Mosquitto {
    child: Option<Child>,
    /// Its port on 127.0.0.1.
    pub port: u16,
    /// `mqtt://127.0.0.1:PORT`, or `mqtts://localhost:PORT`.
    pub url: String,
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
        let mut config = format!(
            "listener {port} 127.0.0.1\npersistence false\nlog_dest stderr\nset_tcp_nodelay true\n\
             # Run as whoever started the test (root in CI), never as another user.\nuser root\n"
        );
        if options.tls {
            let (cert, key) = test_ca().issue(dir.path());
            config.push_str(&format!(
                "cafile {}\ncertfile {}\nkeyfile {}\n",
                test_ca().ca_file().display(),
                cert.display(),
                key.display()
            ));
        }
        if options.users.is_empty() {
            config.push_str("allow_anonymous true\n");
        } else {
            let file = dir.path().join("passwords");
            std::fs::write(&file, "").expect("password file");
            for (user, password) in &options.users {
                let status = Command::new("mosquitto_passwd")
                    .arg("-b")
                    .arg(&file)
                    .args([user, password])
                    .status()
                    .expect("mosquitto_passwd runs");
                assert!(status.success(), "mosquitto_passwd failed");
            }
            config.push_str(&format!(
                "allow_anonymous false\npassword_file {}\n",
                file.display()
            ));
        }
        config.push_str(&options.extra);
        std::fs::write(dir.path().join("mosquitto.conf"), config).expect("config written");
        let scheme = if options.tls {
            "mqtts://localhost"
        } else {
            "mqtt://127.0.0.1"
        };
        let mut broker = Mosquitto {
            child: None,
            port,
            url: format!("{scheme}:{port}"),
            dir,
        };
        broker.run();
        broker
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

/// `lluavd --uplink URL --vehicle-id ID` with `options`, started and
/// online (its retained status says so).
pub async fn vehicle(dir: &Path, broker: &Mosquitto, id: &str, options: Options) -> Lluavd {
    let daemon = Lluavd::start(
        dir,
        &options.with_args(&["--uplink", &broker.url, "--vehicle-id", id]),
    );
    let mut watch = Mqtt::connect(broker, &format!("watch-{id}")).await;
    watch.subscribe(&format!("lluav/{id}/status")).await;
    let start = Instant::now();
    loop {
        let status = watch.json().await;
        if status.1["online"] == true {
            break;
        }
        assert!(
            start.elapsed() < WAIT,
            "{id} never came online:\n{}",
            daemon.stderr()
        );
    }
    daemon
}

/// A plain MQTT client.
pub struct Mqtt {
    client: AsyncClient,
    messages: mpsc::UnboundedReceiver<Publish>,
    acks: mpsc::UnboundedReceiver<()>,
    /// How many of this client's publishes the broker has taken: QoS 0
    /// ones once written, QoS 1 once acknowledged, QoS 2 once completed.
    settled: watch::Receiver<u64>,
    /// How many publishes were handed to the client.
    published: std::sync::atomic::AtomicU64,
    task: tokio::task::JoinHandle<()>,
}

impl Mqtt {
    /// Connects to `broker` as `client_id`, anonymously (trusting the test
    /// CA for `mqtts://`).
    pub async fn connect(broker: &Mosquitto, client_id: &str) -> Mqtt {
        let mut options = MqttOptions::new(client_id, "127.0.0.1", broker.port);
        options.set_max_packet_size(1 << 20, 1 << 20);
        Mqtt::with(options)
            .await
            .unwrap_or_else(|e| panic!("cannot connect: {e}"))
    }

    /// Connects with `options`, or says why not.
    pub async fn with(options: MqttOptions) -> Result<Mqtt, String> {
        let (client, mut events) = AsyncClient::new(options, 10_000);
        let mut network = rumqttc::NetworkOptions::new();
        network.set_tcp_nodelay(true);
        events.set_network_options(network);
        match tokio::time::timeout(WAIT, events.poll()).await {
            Ok(Ok(Event::Incoming(Packet::ConnAck(_)))) => {}
            other => return Err(format!("{other:?}")),
        }
        let (tx, messages) = mpsc::unbounded_channel();
        let (ack_tx, acks) = mpsc::unbounded_channel();
        let (settled_tx, settled) = watch::channel(0u64);
        let task = tokio::spawn(async move {
            loop {
                match events.poll().await {
                    Ok(Event::Incoming(Packet::Publish(p))) => {
                        let _ = tx.send(p);
                    }
                    Ok(Event::Incoming(Packet::SubAck(_))) => {
                        let _ = ack_tx.send(());
                    }
                    Ok(
                        Event::Outgoing(Outgoing::Publish(0))
                        | Event::Incoming(Packet::PubAck(_) | Packet::PubComp(_)),
                    ) => settled_tx.send_modify(|n| *n += 1),
                    Ok(_) => {}
                    Err(_) => return,
                }
            }
        });
        Ok(Mqtt {
            client,
            messages,
            acks,
            settled,
            published: std::sync::atomic::AtomicU64::new(0),
            task,
        })
    }

    /// Subscribes to `filter` and waits until the broker granted it.
    pub async fn subscribe(&mut self, filter: &str) {
        self.client
            .subscribe(filter, QoS::AtLeastOnce)
            .await
            .expect("subscribe queued");
        tokio::time::timeout(WAIT, self.acks.recv())
            .await
            .expect("subscription granted in time");
    }

    /// Publishes `payload` on `topic` and returns once the broker has it
    /// (acknowledged at QoS 1 and 2, written at QoS 0). rumqttc's
    /// `publish` only queues: a test that starts a vehicle next would
    /// otherwise race the client's event loop, which cannot run while the
    /// test's runtime is blocked starting the daemon.
    pub async fn publish(&self, topic: &str, payload: impl Into<Vec<u8>>, qos: QoS, retain: bool) {
        self.client
            .publish(topic, qos, retain, payload)
            .await
            .expect("publish queued");
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
        (p.topic, value)
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

    /// Disconnects.
    pub async fn close(self) {
        let _ = self.client.disconnect().await;
        let _ = tokio::time::timeout(Duration::from_secs(2), self.task).await;
    }
}
