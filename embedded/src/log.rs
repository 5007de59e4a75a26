//! One logging front for both worlds: defmt on the board (feature `defmt`),
//! `log` on std. Without either, the arguments are still type-checked so
//! that a firmware build without logging cannot hide a broken message.

macro_rules! emit {
    ($level:ident, $($arg:tt)*) => {{
        #[cfg(feature = "defmt")]
        ::defmt::$level!($($arg)*);
        #[cfg(all(not(feature = "defmt"), not(target_os = "none")))]
        ::log::$level!($($arg)*);
        #[cfg(all(not(feature = "defmt"), target_os = "none"))]
        let _ = format_args!($($arg)*);
    }};
}

macro_rules! debug {
    ($($arg:tt)*) => { $crate::log::emit!(debug, $($arg)*) };
}

macro_rules! info {
    ($($arg:tt)*) => { $crate::log::emit!(info, $($arg)*) };
}

macro_rules! warning {
    ($($arg:tt)*) => { $crate::log::emit!(warn, $($arg)*) };
}

pub(crate) use {debug, emit, info, warning};
