//! The simulated vehicle: the default backend of `lluavd`.
