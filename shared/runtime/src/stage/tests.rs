//! The runtime's loop with a real WaitSet: alarms end its waits (no sleeping,
//! no polling), another thread's wake-up reaches the stage, and the memory
//! drivers ([`step`], [`step_alarm`]) fire alarms as the loop would.

use std::time::{Duration, Instant};

use super::*;
use crate::names::ServiceNames;
use isochron_config::IpcConfig;

/// A node of its own for one test.
fn ipc(test: &str) -> Ipc {
    let name = format!("isochron-stage-test-{test}-{}", std::process::id());
    Ipc::new(&name, ServiceNames::new(&name), IpcConfig::default()).expect("an iceoryx2 node")
}

/// A source stage: an alarm every `period`, `count` times, counting its passes.
struct Ticker {
    period: Duration,
    count: u32,
    alarms: Vec<Instant>,
    passes: u32,
}

impl Stage for Ticker {
    type Inputs = ();
    const KIND: StageKind = StageKind::Capture;

    fn on_start(&mut self, cx: &mut Context) -> Result<(), Fatal> {
        cx.alarm_in(self.period);
        Ok(())
    }

    fn on_wake(&mut self, _: &(), _: &mut Context) -> Result<(), Fatal> {
        Ok(())
    }

    fn on_alarm(&mut self, cx: &mut Context) -> Result<(), Fatal> {
        self.alarms.push(Instant::now());
        if (self.alarms.len() as u32) < self.count {
            cx.alarm_in(self.period);
        }
        Ok(())
    }

    fn on_tick(&mut self, _: &mut Context) -> Result<(), Fatal> {
        self.passes += 1;
        Ok(())
    }

    fn finished(&self) -> bool {
        self.alarms.len() as u32 >= self.count
    }

    fn counters(&self, _: &mut Counters) {}
}

#[test]
fn alarms_end_the_wait_at_their_time_and_nothing_else_wakes_the_loop() {
    let ipc = ipc("alarms");
    let mut ticker = Ticker {
        period: Duration::from_millis(30),
        count: 10,
        alarms: Vec::new(),
        passes: 0,
    };
    let start = Instant::now();
    let mut cx = Context::unreported(StageKind::Capture);
    run_in(&ipc, &mut ticker, &(), &mut cx).expect("the loop");
    let took = start.elapsed();
    assert_eq!(ticker.alarms.len(), 10);
    assert!(
        took >= Duration::from_millis(300),
        "alarms came early: {took:?}"
    );
    assert!(
        took < Duration::from_millis(600),
        "alarms came late: {took:?}"
    );
    for pair in ticker.alarms.windows(2) {
        let gap = pair[1] - pair[0];
        // An epoll timeout is whole milliseconds, rounded up.
        assert!(gap >= Duration::from_millis(30), "{gap:?}");
        assert!(gap < Duration::from_millis(60), "{gap:?}");
    }
    // One pass per alarm: the tick is due 250 ms after the last pass, so it adds
    // none; a loop that polled or woke early would make many more.
    assert!(ticker.passes <= 10 + 1, "{} passes", ticker.passes);
}

/// A stage with nothing to do but its tick, every `timer`.
struct Periodic {
    timer: Duration,
    ticks: Vec<Instant>,
}

impl Stage for Periodic {
    type Inputs = ();
    const KIND: StageKind = StageKind::Link;

    fn on_wake(&mut self, _: &(), _: &mut Context) -> Result<(), Fatal> {
        Ok(())
    }

    fn on_tick(&mut self, _: &mut Context) -> Result<(), Fatal> {
        self.ticks.push(Instant::now());
        Ok(())
    }

    fn finished(&self) -> bool {
        self.ticks.len() >= 6
    }

    fn timer(&self) -> Duration {
        self.timer
    }

    fn counters(&self, _: &mut Counters) {}
}

#[test]
fn an_idle_stage_ticks_at_its_timer_and_no_more_often() {
    let ipc = ipc("timer");
    let mut periodic = Periodic {
        timer: Duration::from_millis(40),
        ticks: Vec::new(),
    };
    let mut cx = Context::unreported(StageKind::Link);
    run_in(&ipc, &mut periodic, &(), &mut cx).expect("the loop");
    for pair in periodic.ticks.windows(2) {
        let gap = pair[1] - pair[0];
        assert!(gap >= Duration::from_millis(40), "{gap:?}");
        assert!(gap < Duration::from_millis(80), "{gap:?}");
    }
}

/// A stage that waits for another thread: done when woken `count` times.
struct Waiter {
    wakes: u32,
    count: u32,
}

impl Stage for Waiter {
    type Inputs = Wakeup;
    const KIND: StageKind = StageKind::Gate;

    fn on_wake(&mut self, _: &Wakeup, _: &mut Context) -> Result<(), Fatal> {
        // Before the 250 ms idle tick, every pass is a wake-up's.
        self.wakes += 1;
        Ok(())
    }

    fn finished(&self) -> bool {
        self.wakes >= self.count
    }

    fn counters(&self, _: &mut Counters) {}
}

#[test]
fn another_threads_wakeup_wakes_the_stage_at_once() {
    let ipc = ipc("wakeup");
    let (wakeup, waker) = Wakeup::new().expect("a wake-up");
    let mut waiter = Waiter { wakes: 0, count: 3 };
    let thread = std::thread::Builder::new()
        .name("waker".into())
        .spawn(move || {
            for _ in 0..3 {
                std::thread::sleep(Duration::from_millis(20));
                waker.wake();
            }
        })
        .expect("a thread");
    let start = Instant::now();
    let mut cx = Context::unreported(StageKind::Gate);
    run_in(&ipc, &mut waiter, &wakeup, &mut cx).expect("the loop");
    thread.join().expect("the waking thread");
    assert_eq!(waiter.wakes, 3);
    // Woken by each wake-up, not by the 250 ms idle tick.
    assert!(
        start.elapsed() < Duration::from_millis(200),
        "{:?}",
        start.elapsed()
    );
}

#[test]
fn step_fires_a_due_alarm_and_step_alarm_fires_the_next_one_ahead_of_time() {
    let mut ticker = Ticker {
        period: Duration::from_secs(3600),
        count: 3,
        alarms: Vec::new(),
        passes: 0,
    };
    let mut cx = Context::new(StageKind::Capture, "", None);
    ticker.on_start(&mut cx).unwrap();
    let at = cx.alarm().expect("an alarm an hour ahead");
    step(&mut ticker, &(), &mut cx).unwrap();
    assert!(ticker.alarms.is_empty(), "not due: not fired");
    assert_eq!(step_alarm(&mut ticker, &mut cx).unwrap(), Some(at));
    assert_eq!(ticker.alarms.len(), 1);
    cx.alarm_at(Instant::now());
    step(&mut ticker, &(), &mut cx).unwrap();
    assert_eq!(ticker.alarms.len(), 2, "due: fired");
    cx.cancel_alarm();
    assert_eq!(step_alarm(&mut ticker, &mut cx).unwrap(), None);
}
