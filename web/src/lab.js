// The teaching lab: the same page served by a hub (`softhaptic hub`) lists the stations that
// publish to the lab's NATS and shows the one named in the address (`?station=NAME`).
//
// Every server answers `GET /api/stations`; a hub's answer has `hub: true` and the stations,
// and the page then shows the station list, refreshed every two seconds, each entry a link to `?station=NAME` in this tab (the token
// stays in this tab's storage, so a switch needs no new link). The WebSocket, the scene and the
// meshes of a station come from the hub as from the station itself, the station named in the
// query (`/ws?station=NAME`, `/api/scene?station=NAME`; the scene's mesh URLs point at the hub).
//
// `stationOf`, `withStation` and `describeStation` are plain computations (unit-tested);
// `StationList` binds them to the page.

/** A station's name as the server accepts it (a NATS subject token, part of URLs). */
const STATION_NAME = /^[A-Za-z0-9_-]{1,64}$/;

/** The station the page's address names (`?station=NAME`), or null. */
export function stationOf(location) {
  const name = new URLSearchParams(location.search ?? '').get('station');
  return name !== null && STATION_NAME.test(name) ? name : null;
}

/** An archived recording's file name as the hub serves it. */
const ARCHIVE_FILE = /^[A-Za-z0-9._-]{1,200}\.mcap$/;

/** The archived recording the address names (`&archive=FILE`, with a station), or null. */
export function archiveOf(location) {
  const file = new URLSearchParams(location.search ?? '').get('archive');
  return file !== null && ARCHIVE_FILE.test(file) && stationOf(location) !== null ? file : null;
}

/**
 * `path` with the station's query appended, and the archived recording's when given (unchanged
 * for no station).
 */
export function withStation(path, station, archive = null) {
  if (station === null) return path;
  const sep = path.includes('?') ? '&' : '?';
  const file = archive === null ? '' : `&archive=${encodeURIComponent(archive)}`;
  return `${path}${sep}station=${encodeURIComponent(station)}${file}`;
}

/** How long ago `sinceMs` was at `nowMs`, in words: "12 s", "3 min", "2 h". */
export function ago(sinceMs, nowMs) {
  const s = Math.max(0, Math.round((nowMs - sinceMs) / 1000));
  if (s < 60) return `${s} s`;
  if (s < 3600) return `${Math.floor(s / 60)} min`;
  return `${Math.floor(s / 3600)} h`;
}

/** One line of the list: the station's state and since when, its scene, its viewers. */
export function describeStation(s, nowMs) {
  const viewers = s.viewers + s.hub_viewers;
  const watching = viewers === 1 ? '1 viewer' : `${viewers} viewers`;
  return `${s.state} for ${ago(s.since_unix_ms, nowMs)} · ${s.scene} · ${watching}`;
}

/**
 * The line of a station the hub has not heard from since it started but whose sessions are in
 * the archive (a station retired, or a hub started after it stopped).
 */
export function describeArchivedOnly(count) {
  return `not heard by this hub · ${count === 1 ? '1 archived session' : `${count} archived sessions`}`;
}

/** The station list of a hub's page. */
export class StationList {
  constructor({ panel, list, fetchJson, current, currentArchive = null, now = () => Date.now() }) {
    this.panel = panel;
    this.list = list;
    this.fetchJson = fetchJson;
    this.current = current;
    this.currentArchive = currentArchive;
    /** The archived recordings the hub listed: `{station, file, bytes, digest}`. */
    this.archive = [];
    /** Each station's element and its parts, kept across refreshes, by name. */
    this.items = new Map();
    /** The "no station" line, when there is none. */
    this.empty = null;
    this.now = now;
    /** Whether the server is a hub (it answered `/api/stations`); null before it answered. */
    this.isHub = null;
    /** The last list the hub gave. */
    this.stations = [];
  }

  /** Asks the server for its stations; resolves with whether it is a hub. */
  async refresh() {
    const answer = await this.fetchJson('/api/stations');
    this.isHub = answer?.hub === true;
    if (!this.isHub) return false;
    this.stations = Array.isArray(answer?.stations) ? answer.stations : [];
    try {
      const archived = await this.fetchJson('/api/archive');
      this.archive = Array.isArray(archived?.archive) ? archived.archive : [];
    } catch {
      // A lab without an object store yet: no archive to list.
      this.archive = [];
    }
    this.#draw();
    return true;
  }

  /**
   * Draws the list, keeping each station's element from one refresh to the next (only its words
   * and classes change), so a link under the pointer is never replaced while it is clicked.
   */
  #draw() {
    const doc = this.list.ownerDocument;
    this.panel.hidden = false;
    const now = this.now();
    const seen = new Set();
    const heard = new Set(this.stations.map((s) => s.name));
    // Stations with archived sessions that this hub has not heard, after the ones it has: their
    // sessions can be replayed although there is no live view to open.
    const archivedOnly = [...new Set(this.archive.map((a) => a.station))]
      .filter((name) => !heard.has(name))
      .sort()
      .map((name) => ({ name, archivedOnly: true }));
    const items = [...this.stations, ...archivedOnly].map((s) => {
      // Keyed by kind too: a station heard later gets a link in place of its plain name.
      const key = s.archivedOnly ? `archived:${s.name}` : s.name;
      seen.add(key);
      let entry = this.items.get(key);
      if (!entry) {
        const item = doc.createElement('li');
        item.dataset.station = s.name;
        let name;
        if (s.archivedOnly) {
          name = doc.createElement('span');
        } else {
          name = doc.createElement('a');
          name.href = withStation('', s.name);
        }
        name.textContent = s.name;
        const what = doc.createElement('span');
        what.className = 'small muted';
        item.append(name, what);
        entry = { item, what, archiveKey: '', archived: null };
        this.items.set(key, entry);
      }
      const state = s.archivedOnly ? 'archived' : s.state;
      const className = `station ${state}${s.name === this.current ? ' current' : ''}`;
      if (entry.item.className !== className) entry.item.className = className;
      const count = this.archive.filter((a) => a.station === s.name).length;
      const text = ` ${s.archivedOnly ? describeArchivedOnly(count) : describeStation(s, now)}`;
      if (entry.what.textContent !== text) entry.what.textContent = text;
      const recordings = this.archive.filter((a) => a.station === s.name);
      const archiveKey = recordings.map((a) => a.file).join('\n');
      if (archiveKey !== entry.archiveKey) {
        entry.archiveKey = archiveKey;
        entry.archived?.remove();
        entry.archived = null;
        if (recordings.length > 0) {
          const archived = doc.createElement('ul');
          archived.className = 'archived';
          archived.append(
            ...recordings.map((a) => {
              const li = doc.createElement('li');
              li.dataset.archive = a.file;
              if (s.name === this.current && a.file === this.currentArchive) li.className = 'current';
              const replay = doc.createElement('a');
              replay.href = withStation('', s.name, a.file);
              replay.textContent = `replay ${a.file}`;
              li.append(replay);
              return li;
            }),
          );
          entry.item.append(archived);
          entry.archived = archived;
        }
      }
      return entry.item;
    });
    for (const name of [...this.items.keys()]) {
      if (!seen.has(name)) this.items.delete(name);
    }
    if (items.length === 0) {
      this.empty ??= doc.createElement('li');
      this.empty.className = 'muted';
      this.empty.textContent = 'no station has published yet';
      items.push(this.empty);
    }
    // Only when the stations or their order changed: moving an element detaches it for a moment.
    const current = [...this.list.children];
    if (current.length !== items.length || current.some((el, i) => el !== items[i])) {
      this.list.replaceChildren(...items);
    }
  }
}
