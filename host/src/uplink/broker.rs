//! The MQTT connection options both ends use: the vehicle's uplink and the
//! operator's fleet client (rumqttc's MQTT 5 client, clean start, no
//! session expiry, rustls).

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use rumqttc::v5::MqttOptions;
use rumqttc::{NetworkOptions, TlsConfiguration, Transport};

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
    /// User name at the broker.
    pub user: Option<&'a str>,
    /// The password at the broker.
    pub password: Option<&'a str>,
    /// CA certificates for `mqtts://` instead of the system's.
    pub cafile: Option<&'a Path>,
    /// The largest packet this end takes, sent as the CONNECT's Maximum
    /// Packet Size: the broker drops anything larger instead of sending it
    /// (MQTT 5, 3.1.2.11), so no message can cost the connection.
    pub max_packet: u32,
    /// Requests the client may queue for the connection.
    pub queue: usize,
    /// QoS 1 messages sent and not yet acknowledged, at most (the broker's
    /// Receive Maximum may make it fewer): each one waits in memory.
    pub in_flight: u16,
}

impl Dial<'_> {
    /// The options; fails only on an unusable CA file.
    pub fn options(&self) -> Result<MqttOptions, ClientError> {
        let mut options = MqttOptions::new(self.client_id, &self.broker.host, self.broker.port);
        options
            .set_keep_alive(KEEP_ALIVE)
            // Nothing sent while this end was away is delivered late, and
            // nothing this end queued is sent after a reconnect: a clean
            // start, and a session that ends with the connection.
            .set_clean_start(true)
            .set_session_expiry_interval(None)
            .set_max_packet_size(Some(self.max_packet))
            .set_request_channel_capacity(self.queue)
            .set_outgoing_inflight_upper_limit(self.in_flight)
            .set_connection_timeout(CONNECT_TIMEOUT_S)
            // Acknowledged as read: the broker redelivers nothing within a
            // connection, and a clean start forgets what was not
            // acknowledged, so waiting would only make the acknowledgements
            // queue up (a broker that floods and never reads).
            .set_manual_acks(false);
        let mut network = NetworkOptions::new();
        // Small messages go out at once: Nagle's delay would add tens of
        // milliseconds to every round trip.
        network.set_tcp_nodelay(true);
        network.set_connection_timeout(CONNECT_TIMEOUT_S);
        options.set_network_options(network);
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
