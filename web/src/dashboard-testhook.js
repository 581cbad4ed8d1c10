// What the browser tests read of the dashboard (web/tests/e2e-dashboard.test.mjs): loaded only
// under automation (`navigator.webdriver`), by a dynamic import, so no other browser downloads it.

/** Installs `window.__dashboard`: plain data about the page, read through `page.evaluate`. */
export function installDashboardHook({ page, connection, act }) {
  window.__dashboard = {
    /** `hello.role`, null before it came. */
    role: () => page.role,
    /** The connection's state and counters. */
    connection: () => {
      const c = connection();
      return { state: c.state, stats: { ...c.stats }, lastError: c.lastError };
    },
    /** The latest `dashboard` message, as received. */
    message: () => page.message,
    /** Each tile in the page's order: what it shows and which of its controls are offered. */
    tiles: () =>
      [...document.querySelectorAll('#tiles .tile')].map((el) => ({
        name: el.dataset.station,
        alert: el.classList.contains('alert'),
        offline: el.classList.contains('offline'),
        activity: el.querySelector('.activity').textContent,
        trainee: el.querySelector('.trainee').textContent,
        device: el.querySelector('.device').textContent,
        href: el.querySelector('.name').getAttribute('href'),
        openAlerts: [...el.querySelectorAll('.tile-alerts li[data-alert]')].map((li) => ({
          id: Number(li.dataset.alert),
          kind: li.dataset.kind,
        })),
        actionsShown: !el.querySelector('.actions').hidden,
        ackButtons: el.querySelectorAll('button.ack').length,
        rearmShown: !el.querySelector('button[data-act="rearm"]').hidden,
        result: el.querySelector('.result').textContent,
      })),
    /** The force history the page keeps for `name` (null slots where no sample came). */
    history: (name) => page.histories.get(name)?.values() ?? null,
    /**
     * Sends a station action as the page's controls do, whether or not it offers them (an
     * observer's, to see the hub refuse it).
     */
    act: (station, action) => act(station, action),
    /** Every action the page sent. */
    sent: () => page.sent.map((s) => ({ ...s })),
    /** The alert list's entries. */
    alertList: () =>
      [...document.querySelectorAll('#alert-list li')].map((li) => ({
        station: li.dataset.station,
        id: Number(li.dataset.alert),
        open: li.classList.contains('open'),
        text: li.textContent,
      })),
  };
}
