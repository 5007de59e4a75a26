//! The daemon's recent log messages, for `showmsg` and `savemsg`.
