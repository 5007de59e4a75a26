//! The MQTT connection options both ends use: the vehicle's uplink and the
//! operator's fleet client (rumqttc, MQTT 3.1.1, clean session, rustls).

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use rumqttc::{EventLoop, MqttOptions, NetworkOptions, TlsConfiguration, Transport};

use super::config::BrokerUrl;
use crate::client::{ClientError, tls_config};

/// MQTT keep-alive: a broker notices a vanished peer (and publishes its
/// will) within one and a half of these.
pub const KEEP_ALIVE: Duration = Duration::from_secs(10);

/// Seconds allowed for TCP, TLS and MQTT's CONNECT together.
const CONNECT_TIMEOUT_S: u64 = 5;

/// Who connects, and how.
pub struct Dial<'a> {
    /// The broker.
    pub broker: &'a BrokerUrl,
    /// The MQTT client id.
    pub client_id: &'a str,
    /// User name and password at the broker.
    pub user: Option<&'a str>,
    /// The password at the broker.
    pub password: Option<&'a str>,
    /// CA certificates for `mqtts://` instead of the system's.
    pub cafile: Option<&'a Path>,
    /// Largest packet read, and written, in bytes.
    pub max_packet: (usize, usize),
    /// Requests the client may queue for the connection.
    pub queue: usize,
    /// Acknowledge QoS 1 messages only when told to.
    pub manual_acks: bool,
}

impl Dial<'_> {
    /// The options; fails only on an unusable CA file.
    pub fn options(&self) -> Result<MqttOptions, ClientError> {
        let mut options = MqttOptions::new(self.client_id, &self.broker.host, self.broker.port);
        options
            .set_keep_alive(KEEP_ALIVE)
            // Nothing sent while this end was away is delivered late, and
            // nothing this end queued is sent after a reconnect.
            .set_clean_session(true)
            .set_max_packet_size(self.max_packet.0, self.max_packet.1)
            .set_request_channel_capacity(self.queue)
            .set_manual_acks(self.manual_acks);
        if let Some(user) = self.user {
            options.set_credentials(user, self.password.unwrap_or_default());
        }
        if self.broker.tls {
            let config = tls_config(self.cafile)?;
            options.set_transport(Transport::tls_with_config(TlsConfiguration::Rustls(Arc::new(
                config,
            ))));
        }
        Ok(options)
    }
}

/// Sets the connection's socket options: no Nagle delay on small
/// messages, a bounded connect.
pub fn tune(events: &mut EventLoop) {
    let mut network = NetworkOptions::new();
    network.set_tcp_nodelay(true);
    network.set_connection_timeout(CONNECT_TIMEOUT_S);
    events.set_network_options(network);
}
