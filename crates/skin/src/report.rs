//! How `skin` words an error for people: its whole chain of causes, each
//! once.
//!
//! Many library errors already say their cause in their own message (`cannot
//! open X: No such file or directory; hint`) and also hand it on as their
//! [`source`](std::error::Error::source), so that programs can inspect it.
//! Printing the chain naively (anyhow's `{:#}`) then says every such cause
//! twice. [`causes_once`] prints a cause only if the text so far does not
//! already contain it.

/// `error` and its causes, joined by `": "`, leaving out every cause whose
/// text the message already holds.
pub fn causes_once(error: &(dyn std::error::Error + 'static)) -> String {
    let mut text = error.to_string();
    let mut cause = error.source();
    while let Some(next) = cause {
        let said = next.to_string();
        if !said.is_empty() && !text.contains(&said) {
            text.push_str(": ");
            text.push_str(&said);
        }
        cause = next.source();
    }
    text
}

#[cfg(test)]
mod tests {
    use super::causes_once;

    #[derive(Debug, thiserror::Error)]
    #[error("cannot open {url}: {source}; is the adapter plugged in?")]
    struct Open {
        url: &'static str,
        source: std::io::Error,
    }

    #[derive(Debug, thiserror::Error)]
    #[error("driver torso failed to start")]
    struct Start {
        #[source]
        source: Open,
    }

    #[test]
    fn a_cause_already_in_the_message_is_said_once() {
        let open = Open { url: "slcan:///tmp/x", source: std::io::ErrorKind::NotFound.into() };
        let error = anyhow::Error::new(Start { source: open }).context("skin nodev");
        // anyhow's own chain says the OS error twice.
        assert_eq!(format!("{error:#}").matches("entity not found").count(), 2);
        let text = causes_once(error.as_ref());
        assert_eq!(
            text,
            "skin nodev: driver torso failed to start: cannot open slcan:///tmp/x: entity not found; is the adapter plugged in?"
        );
    }

    #[test]
    fn causes_not_yet_said_are_all_kept_in_order() {
        let error = anyhow::anyhow!("innermost").context("middle").context("outer");
        assert_eq!(causes_once(error.as_ref()), "outer: middle: innermost");
    }
}
