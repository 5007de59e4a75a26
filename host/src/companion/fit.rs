//! Lists with no natural bound (log lines, files) answer as many entries
//! as fit, newest first, and say `"truncated": true` when some were left
//! out, for any reason (a count argument included), and how many there
//! are, `"total"`: no number of files or log lines can make such a command
//! answer `Response too large`.

use lluav_core::Fields;

/// Bytes of JSON one list's entries may take in an answer: lluavd's
/// response buffer is 64 KiB, and what else a list answer holds is far
/// under the 16 KiB left.
pub(crate) const LIST_BUDGET: usize = 48 * 1024;

/// The leading entries of `entries` whose JSON (`json_len` bytes each,
/// with a comma between) fits [`LIST_BUDGET`], and whether some were left
/// out.
pub(crate) fn fitting<T>(entries: Vec<T>, json_len: impl Fn(&T) -> usize) -> (Vec<T>, bool) {
    let mut used = 0usize;
    let fit = entries
        .iter()
        .take_while(|e| {
            used = used.saturating_add(json_len(e) + 1);
            used <= LIST_BUDGET
        })
        .count();
    let truncated = fit < entries.len();
    let mut entries = entries;
    entries.truncate(fit);
    (entries, truncated)
}

/// The bytes `s` takes as a JSON string, quotes and escapes included.
pub(crate) fn json_str_len(s: &str) -> usize {
    2 + s
        .chars()
        .map(|c| match c {
            '"' | '\\' | '\n' | '\r' | '\t' => 2,
            c if u32::from(c) < 0x20 => 6,
            c => c.len_utf8(),
        })
        .sum::<usize>()
}

/// Writes `key` as an array of the strings that fit, then whether any of
/// the `total` there are were left out, and `total`.
pub(crate) fn write_strings(out: &mut Fields<'_>, key: &str, strings: Vec<String>, total: usize) {
    let (strings, _) = fitting(strings, |s| json_str_len(s));
    out.array(key, |a| {
        strings.iter().for_each(|s| {
            a.str(s);
        })
    });
    write_counts(out, strings.len(), total);
}

/// `truncated` (fewer than `total` shown) and `total`.
pub(crate) fn write_counts(out: &mut Fields<'_>, shown: usize, total: usize) {
    out.bool("truncated", shown < total).u64("total", total as u64);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn entries_fit_the_budget_in_order_and_the_rest_is_reported_left_out() {
        let lines: Vec<String> = (0..100).map(|i| format!("{i:0>1000}")).collect();
        let (kept, truncated) = fitting(lines.clone(), |s| json_str_len(s));
        assert!(truncated);
        assert_eq!(kept.len(), LIST_BUDGET / 1003);
        assert_eq!(kept[..], lines[..kept.len()]);
        let (all, truncated) = fitting(lines[..3].to_vec(), |s| json_str_len(s));
        assert_eq!((all.len(), truncated), (3, false));
    }

    #[test]
    fn json_lengths_count_quotes_and_escapes() {
        assert_eq!(json_str_len("ab"), 4);
        assert_eq!(json_str_len("a\"b\\"), 8);
        assert_eq!(json_str_len("\u{1}é"), 2 + 6 + 2);
        assert_eq!(
            serde_json::to_string("a\"\u{1}é\n").unwrap().len(),
            json_str_len("a\"\u{1}é\n")
        );
    }
}
