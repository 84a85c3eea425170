// What the pages' scripts (static/web/*.js) find on the page besides the DOM: the vendor
// libraries their templates load before them, and what the shared scripts (api.js,
// wall_clock.js, live.js) put on `window`. The vendor libraries are checked by their own
// projects and typed loosely here; the page scripts' own globals are typed as they are used.

/** luxon's global build (vendor/luxon/luxon.min.js). */
declare const luxon: any;
/** Event Calendar's browser build (vendor/event-calendar/event-calendar.min.js): the calendar
 * and the timeline. */
declare const EventCalendar: any;
/** Chart.js's UMD build (vendor/chart.js/chart.umd.js): run, compare, builder and usage pages. */
declare const Chart: any;
/** js-yaml's UMD build (vendor/js-yaml/js-yaml.umd.min.js): the experiment builder. */
declare const jsyaml: any;

/** api.js: what a request comes to. `data` is null when the answer was not JSON, `status` 0
 * when there was no answer at all. */
interface AmazingAnswer {
  ok: boolean;
  status: number;
  data: any;
}

interface AmazingApiOptions {
  /** Headers besides the CSRF token and the client's name. */
  headers?: Record<string, string>;
  /** The request outlives the page. */
  keepalive?: boolean;
}

interface AmazingApi {
  api(method: string, url: string, body?: unknown, options?: AmazingApiOptions): Promise<AmazingAnswer>;
  /** The API's refusal ({detail, fields}) as one sentence. */
  explain(data: any): string;
  /** Why a request came to nothing, in a few words ("no answer", "HTTP 502", ...). */
  failure(answer: AmazingAnswer): string;
}

/** wall_clock.js: a typed wall-clock time read as an instant, or why it cannot be. */
interface AmazingLocalInstant {
  iso?: string;
  offset?: string;
  repeated?: boolean;
  error?: string;
}

interface AmazingWallClock {
  localInstant(value: string, zone: string): AmazingLocalInstant;
  typedWindow(startValue: string, endValue: string, zone: string): { start?: string; end?: string; note?: string; error?: string };
  /** An instant as the testbed's wall-clock time without an offset ("2027-03-29T10:00:00"). */
  floating(iso: string, zone: string): string;
  /** An Event Calendar date as the instant (a luxon DateTime) in the testbed's zone. */
  wall(date: Date, zone: string): any;
  /** The zone's offset in force now ("+00:00"). */
  offsetNow(zone: string): string;
  /** Whether the browser's clock shows the zone's wall-clock time now. */
  browserShowsZone(zone: string): boolean;
}

/** event_calendar.js: what the calendar and the timeline do alike to Event Calendar. */
interface AmazingEventCalendar {
  /** Keep Event Calendar's drawing in `el` free of table roles it does not fill. */
  keepPlain(el: HTMLElement): void;
}

/** live.js: what a page follows, and how. */
interface LiveFollowOptions {
  events?: Record<string, (data: any) => void>;
  poll?: () => void;
  pollMs?: number;
  safetyMs?: number;
  indicator?: HTMLElement | null;
}

interface LiveFollow {
  stop(): void;
}

interface Window {
  AmazingApi: AmazingApi;
  AmazingWallClock: AmazingWallClock;
  AmazingEventCalendar: AmazingEventCalendar;
  liveFollow: (url: string, options: LiveFollowOptions) => LiveFollow;
}

/** live.js sets it on `window`; the pages call it by its bare name. */
declare function liveFollow(url: string, options: LiveFollowOptions): LiveFollow;

/** The booking dialogs' forms (calendar.html, timeline.html: _booking_fields.html), their
 * fields by name. A form's fields hide its own properties of the same name: `form.title` is
 * the field named "title", not the form's title attribute. */
type BookingForm = HTMLFormElement & {
  experiment: HTMLSelectElement;
  start: HTMLInputElement;
  end: HTMLInputElement;
  title: HTMLInputElement;
};

/** What the run page (run.js: each answer of the run's data) and the robot console (robot.js:
 * each status reading) tell the other scripts on the page (roof.js). */
interface DocumentEventMap {
  "run:data": CustomEvent;
  "robot:status": CustomEvent;
}
