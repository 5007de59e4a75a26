//! Cross-crate integration tests: they drive the real servers over real
//! sockets once the adapters exist (see the host and embedded issues).
