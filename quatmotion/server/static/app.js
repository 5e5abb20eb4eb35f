/*
 * quatmotion web app: the pages' script. Every page calls the JSON API under /api/ and shows
 * clips with the viewer of quatmotion.viz (window.QuatmotionViewer, served from
 * /assets/viewer/). Text from the server (clip names, labels, messages) is only ever set as
 * textContent, never as HTML.
 *
 * The page is chosen by <body data-page="...">: browse, play, compare, search, poses.
 * For tests and people alike, <html> carries data-state="ready" once a page has shown what it
 * fetched, data-error with the message when something failed, and window.quatmotionViewer is
 * the last viewer mounted.
 */
(function () {
  'use strict';

  const $ = (selector, root) => (root || document).querySelector(selector);
  const params = new URLSearchParams(location.search);

  function el(tag, attrs, children) {
    const node = document.createElement(tag);
    for (const key in attrs || {}) {
      const value = attrs[key];
      if (value === undefined || value === null || value === false) continue;
      if (key === 'text') node.textContent = value;
      else if (key === 'class') node.className = value;
      else if (key.startsWith('on')) node.addEventListener(key.slice(2), value);
      else node.setAttribute(key, value === true ? '' : value);
    }
    for (const child of children || []) if (child) node.appendChild(typeof child === 'string' ? document.createTextNode(child) : child);
    return node;
  }

  /** JSON from the API; a failure throws an Error carrying the server's one-line detail. */
  async function api(path, options) {
    const request = Object.assign({}, options || {});
    if (request.method && request.method !== 'GET') {
      // The server refuses a POST without it (its guard against cross-site request forgery).
      request.headers = Object.assign({ 'X-Quatmotion-Request': '1' }, request.headers || {});
    }
    let response = await fetch(path, request);
    // 503 with Retry-After: the library is still being built and what was asked may come.
    for (let waited = 0; response.status === 503 && response.headers.get('Retry-After') && !request.method && waited < 3600; ) {
      const pause = Math.max(1, Number(response.headers.get('Retry-After')) || 2);
      let detail = '';
      try { detail = (await response.json()).detail || ''; } catch (_) { /* keep waiting */ }
      status('Waiting: ' + detail);
      await new Promise((done) => setTimeout(done, 1000 * pause));
      waited += pause;
      response = await fetch(path, request);
    }
    let body = null;
    try { body = await response.json(); } catch (_) { /* not JSON: the status says it */ }
    if (!response.ok) {
      const detail = body && body.detail ? (typeof body.detail === 'string' ? body.detail : JSON.stringify(body.detail)) : response.statusText;
      throw new Error(detail + ' (HTTP ' + response.status + ')');
    }
    return body;
  }

  const url = (path, query) => path + '?' + new URLSearchParams(query).toString();
  const enc = encodeURIComponent;

  function status(message, isError) {
    const node = $('#status');
    if (node) { node.textContent = message || ''; node.classList.toggle('error', !!isError); }
    if (isError) document.documentElement.dataset.error = message;
  }

  function ready(state) { document.documentElement.dataset.state = state || 'ready'; }

  function fail(error) {
    status(error.message || String(error), true);
    ready('failed');
  }

  const fixed = (x, n) => (x === null || x === undefined ? '\u2013' : Number(x).toFixed(n));
  function bytes(n) {
    if (n === null || n === undefined) return '\u2013';
    if (n < 1e3) return n + ' B';
    if (n < 1e6) return (n / 1e3).toFixed(1) + ' kB';
    return (n / 1e6).toFixed(2) + ' MB';
  }

  // ---------------------------------------------------------------- viewers
  const viewers = new Map();

  /** Show a view document (quatmotion.viz.view_data shape) on `element`, replacing any viewer there. */
  async function show(element, data) {
    const old = viewers.get(element);
    if (old) { old.dispose(); viewers.delete(element); }
    const viewer = await QuatmotionViewer.show(element, data);
    viewers.set(element, viewer);
    window.quatmotionViewer = viewer;
    return viewer;
  }

  function view(payloads, options) {
    return Object.assign({ clips: payloads, pairs: [], layout: payloads.length > 1 ? 'side' : 'overlay', ghost: 0, autoplay: true, loop: true }, options || {});
  }

  // ---------------------------------------------------------------- header
  async function header() {
    const page = document.body.dataset.page;
    const nav = el('header', {}, [
      el('a', { class: 'brand', href: '/', text: 'quatmotion' }),
      el('a', { href: '/', text: 'Library', class: page === 'browse' ? 'here' : null }),
      el('a', { href: '/search', text: 'Search by example', class: page === 'search' ? 'here' : null }),
      el('a', { href: '/docs', text: 'API' }),
      el('span', { class: 'served', id: 'served' }),
    ]);
    document.body.prepend(nav);
    const info = await api('/api/info');
    const files = [info.library, info.index, info.poses].filter(Boolean).join(' \u00b7 ');
    $('#served').textContent = files + ' \u00b7 ' + info.clips + ' clips';
    if (info.building) watchBuild(nav);
    return info;
  }

  // ---------------------------------------------------------------- a library being built
  const STAGES = { index: 'listed, playable and searchable', library: 'compressed: compare', poses: 'pose search' };

  /**
   * A banner under the header while the server builds its library (quatmotion serve DIR):
   * the step and its progress, polled from /api/build; each stage served fires the event
   * 'quatmotion:stage' on document (the library page reloads its list). <html> carries
   * data-build with the build's state.
   */
  function watchBuild(nav) {
    const bar = el('progress', { max: '1', value: '0' });
    const text = el('span', { class: 'build-step' });
    const banner = el('div', { class: 'build', id: 'build', role: 'status' }, [text, bar]);
    nav.after(banner);
    let served = 0;
    async function poll() {
      let build;
      try { build = await api('/api/build'); } catch (error) { text.textContent = 'build: ' + error.message; return setTimeout(poll, 3000); }
      document.documentElement.dataset.build = build.state;
      banner.className = 'build ' + build.state;
      const got = build.served.map((s) => STAGES[s] || s).join('; ');
      if (build.state === 'building') {
        bar.max = Math.max(1, build.total);
        bar.value = build.done;
        text.textContent = 'Building ' + build.source + ': ' + build.step + (build.total ? ' ' + build.done + '/' + build.total : '') +
          ' \u00b7 ' + Math.round(build.seconds) + ' s' + (got ? ' \u00b7 ' + build.clips + ' clips ' + got : ' \u00b7 the clips appear when they are indexed');
      } else {
        bar.remove();
        const left = build.failed.length ? ' \u00b7 ' + build.failed.length + ' files left out' : '';
        text.textContent = build.state === 'ready'
          ? 'Built ' + build.source + ' in ' + Math.round(build.seconds) + ' s: ' + build.clips + ' clips' + left
          : 'The build of ' + build.source + ' ' + (build.state === 'failed' ? 'failed: ' + build.message : 'stopped') + left;
        if (build.failed.length) {
          banner.appendChild(el('details', {}, [el('summary', { text: 'left out' }),
            ...build.failed.map((f) => el('div', { text: f }))]));
        }
      }
      if (build.served.length !== served) {
        served = build.served.length;
        api('/api/info').then((info) => {
          const names = [info.library, info.index, info.poses].filter(Boolean).join(' \u00b7 ');
          $('#served').textContent = names + ' \u00b7 ' + info.clips + ' clips';
        }).catch(() => {});
        document.dispatchEvent(new CustomEvent('quatmotion:stage', { detail: build }));
      }
      if (build.state === 'building') setTimeout(poll, 1000);
    }
    poll();
  }

  function clipLinks(clip) {
    const q = '?clip=' + enc(clip.id);
    return [
      el('a', { href: '/play' + q, text: 'play' }),
      clip.in_library && clip.has_original ? el('a', { href: '/compare' + q, text: 'compare', title: 'original beside decoded' }) : null,
      clip.in_index ? el('a', { href: '/search' + q, text: 'similar', title: 'search by this clip' }) : null,
      clip.in_poses ? el('a', { href: '/poses' + q, text: 'poses', title: 'pose search' }) : null,
    ];
  }

  function facts(clip) {
    const items = [
      ['frames', clip.frames], ['duration', fixed(clip.duration_s, 2) + ' s'], ['fps', clip.fps],
      ['label', clip.label || '\u2013'],
    ];
    if (clip.in_library) {
      items.push(['compressed', bytes(clip.compressed_bytes)]);
      items.push(['declared max error', fixed(clip.declared_max_error_cm, 3) + ' cm']);
      items.push(['declared ARMS', fixed(clip.declared_arms_cm, 3) + ' cm']);
    }
    return el('div', { class: 'facts' }, items.map(([k, v]) => el('span', {}, [k + ' ', el('b', { text: String(v) })])));
  }

  // ---------------------------------------------------------------- browse
  const COLUMNS = [
    ['name', 'name', false], ['label', 'label', false], ['frames', 'frames', true],
    ['duration_s', 'duration (s)', true], ['compressed_bytes', 'compressed', true],
    ['declared_max_error_cm', 'declared max error (cm)', true], ['declared_arms_cm', 'declared ARMS (cm)', true],
  ];

  async function browse() {
    await header();
    const state = { label: params.get('label'), sort: params.get('sort') || 'name', order: params.get('order') || 'asc' };
    const select = $('#label');
    select.addEventListener('change', () => { state.label = select.value === '*' ? null : select.value; load(); });

    async function load() {
      const query = { sort: state.sort, order: state.order };
      if (state.label !== null) query.label = state.label;
      history.replaceState(null, '', url('/', query));
      status('Loading\u2026');
      const data = await api(url('/api/clips', query));
      select.replaceChildren(el('option', { value: '*', text: 'all labels' }),
        ...data.labels.map((l) => el('option', { value: l, text: l || '(unlabelled)' })));
      select.value = state.label === null ? '*' : state.label;
      const head = el('tr', {}, [
        ...COLUMNS.map(([key, title, num]) => el('th', { class: num ? 'num' : null }, [
          el('button', {
            'data-sort': key, text: title + (state.sort === key ? (state.order === 'asc' ? ' \u25b2' : ' \u25bc') : ''),
            onclick: () => { state.order = state.sort === key && state.order === 'asc' ? 'desc' : 'asc'; state.sort = key; load().catch(fail); },
          }),
        ])),
        el('th', { text: '' }),
      ]);
      const rows = data.clips.map((c) => el('tr', { 'data-id': c.id }, [
        el('td', {}, [el('a', { href: '/play?clip=' + enc(c.id), text: c.name })]),
        el('td', { text: c.label || '\u2013' }),
        el('td', { class: 'num', text: String(c.frames) }),
        el('td', { class: 'num', text: fixed(c.duration_s, 2) }),
        el('td', { class: 'num', text: bytes(c.compressed_bytes) }),
        el('td', { class: 'num', text: fixed(c.declared_max_error_cm, 3) }),
        el('td', { class: 'num', text: fixed(c.declared_arms_cm, 3) }),
        el('td', { class: 'actions' }, clipLinks(c)),
      ]));
      $('#clips').replaceChildren(el('thead', {}, [head]), el('tbody', {}, rows));
      status(data.clips.length + ' clips' + (state.label !== null ? ' labelled \u201c' + (state.label || '(unlabelled)') + '\u201d' : ''));
      ready();
    }
    document.addEventListener('quatmotion:stage', () => load().catch(fail));
    await load();
  }

  // ---------------------------------------------------------------- play / compare
  function clipParam() {
    const id = params.get('clip');
    if (!id) throw new Error('no clip given: open a clip from the library page');
    return id;
  }

  async function play() {
    await header();
    const id = clipParam();
    const clip = await api('/api/clips/' + enc(id));
    $('h1').textContent = clip.name;
    $('#facts').replaceWith(facts(clip));
    $('#links').replaceChildren(...clipLinks(clip).filter(Boolean).slice(1));
    status('Loading the frames\u2026');
    const payload = await api('/api/clips/' + enc(id) + '/frames');
    await show($('#viewer'), view([payload]));
    status('');
    ready();
  }

  async function compare() {
    await header();
    const id = clipParam();
    const clip = await api('/api/clips/' + enc(id));
    $('h1').textContent = clip.name + ': original and decoded';
    $('#facts').replaceWith(facts(clip));
    status('Decoding and reading the original\u2026');
    const data = await api('/api/clips/' + enc(id) + '/compare');
    const pair = data.pairs[0];
    status(pair.errors
      ? 'measured: ARMS ' + fixed(pair.arms_cm, 3) + ' cm, max ' + fixed(pair.max_cm, 3) +
        ' cm over every joint and end site (declared max ' + fixed(clip.declared_max_error_cm, 3) + ' cm)'
      : 'no per-frame error: ' + pair.no_error);
    await show($('#viewer'), data);
    ready();
  }

  // ---------------------------------------------------------------- search by example
  async function search() {
    const info = await header();
    const form = $('#query');
    const methods = $('#method');
    methods.replaceChildren(...info.methods.map((m) => el('option', { value: m, text: m + (m === info.default_method ? ' (default)' : '') })));
    if (!info.methods.length) {
      status(info.index ? 'The index holds no search features: rebuild it (quatmotion index build).'
        : 'This server has no index (.qidx): start it with --index to search.', true);
      ready('failed');
      return;
    }
    const indexed = (await api('/api/clips')).clips.filter((c) => c.in_index);
    const pick = $('#clip');
    pick.replaceChildren(...indexed.map((c) => el('option', { value: c.id, text: c.name + (c.label ? ' (' + c.label + ')' : '') })));
    if (params.get('clip')) pick.value = params.get('clip');
    $('#max-upload').textContent = bytes(info.max_upload_bytes);
    const viewerNode = $('#viewer');
    let query = null; // {payload, id}

    function mode() { return form.elements.source.value; }
    form.elements.source.forEach((r) => r.addEventListener('change', () => {
      $('#by-clip').hidden = mode() !== 'clip'; $('#by-upload').hidden = mode() !== 'upload';
    }));

    async function run() {
      status('Searching\u2026');
      delete document.documentElement.dataset.error;
      document.documentElement.dataset.state = 'searching';
      const top = form.elements.top.value || '20';
      let response;
      if (mode() === 'clip') {
        response = await api(url('/api/search', { clip: pick.value, method: methods.value, top }));
        query = { id: response.query_id, payload: await api('/api/clips/' + enc(response.query_id) + '/frames') };
      } else {
        const file = form.elements.file.files[0];
        if (!file) throw new Error('choose an .amc or .bvh file to upload');
        const body = new FormData();
        body.append('file', file, file.name);
        const asf = form.elements.asf.files[0];
        if (asf) body.append('asf', asf, asf.name);
        body.append('method', methods.value);
        body.append('top', top);
        response = await api('/api/search/upload', { method: 'POST', body });
        query = { id: null, payload: response.query_clip };
      }
      const list = $('#results');
      list.replaceChildren(...response.results.map((r) => el('li', { 'data-id': r.id || '', 'data-rank': String(r.rank) }, [
        el('span', { class: 'rank', text: String(r.rank) }),
        el('span', { class: 'name', text: r.clip + (r.label ? ' (' + r.label + ')' : ''), title: r.clip }),
        el('span', { class: 'distance', text: r.distance === null ? '\u2013' : Number(r.distance).toPrecision(4) }),
        r.id ? el('button', { class: 'play-result', type: 'button', text: 'play beside', onclick: (ev) => playResult(ev.target.closest('li'), r).catch(fail) }) : null,
      ])));
      $('#summary').textContent = response.results.length + ' results for ' + response.query + ' by ' + response.method +
        ' in ' + (1000 * response.seconds).toFixed(0) + ' ms' +
        (response.left_out ? '; ' + response.left_out + ', the query itself, left out' : '');
      status('');
      await show(viewerNode, view([query.payload]));
      ready();
    }

    async function playResult(item, result) {
      for (const li of document.querySelectorAll('#results li.selected')) li.classList.remove('selected');
      item.classList.add('selected');
      status('Loading ' + result.clip + '\u2026');
      document.documentElement.dataset.state = 'loading';
      const payload = await api('/api/clips/' + enc(result.id) + '/frames');
      await show(viewerNode, view([query.payload, payload]));
      document.documentElement.dataset.playingResult = result.id;
      status('');
      ready();
    }

    form.addEventListener('submit', (ev) => { ev.preventDefault(); run().catch(fail); });
    ready('idle');
    if (params.get('clip') && pick.value === params.get('clip')) await run();
  }

  // ---------------------------------------------------------------- pose search
  async function poses() {
    const info = await header();
    const id = clipParam();
    if (!info.poses) throw new Error('This server has no pose index: start it with --poses to search poses.');
    const clip = await api('/api/clips/' + enc(id));
    $('h1').textContent = 'Poses like a frame of ' + clip.name;
    const payload = await api('/api/clips/' + enc(id) + '/frames');
    const main = await show($('#viewer'), view([payload], { autoplay: false }));
    const start = Number(params.get('frame') || 0);
    main.seek(Math.min(Math.max(0, start), clip.frames - 1));
    const form = $('#query');

    async function run() {
      const frame = main.frame;
      status('Searching poses like frame ' + frame + '\u2026');
      const response = await api(url('/api/poses', { clip: id, frame, k: form.elements.k.value, other_clips: form.elements.other.checked }));
      const list = $('#results');
      list.replaceChildren(...response.results.map((r) => el('li', { 'data-id': r.id || '' }, [
        el('span', { class: 'rank', text: String(r.rank) }),
        el('span', { class: 'name', text: r.clip + ' frame ' + r.frame + (r.seconds === null ? '' : ' (' + r.seconds.toFixed(2) + ' s)') }),
        el('span', { class: 'distance', text: r.distance.toPrecision(4) }),
        r.id ? el('button', { type: 'button', class: 'show-pose', text: 'show', onclick: (ev) => showPose(ev.target.closest('li'), response.frame, r).catch(fail) }) : null,
      ])));
      $('#summary').textContent = 'nearest poses to frame ' + response.frame + ' of ' + clip.name;
      status('');
      ready();
    }

    async function showPose(item, frame, hit) {
      for (const li of document.querySelectorAll('#results li.selected')) li.classList.remove('selected');
      item.classList.add('selected');
      const [a, b] = await Promise.all([
        api(url('/api/clips/' + enc(id) + '/frames', { start: frame, stop: frame + 1 })),
        api(url('/api/clips/' + enc(hit.id) + '/frames', { start: hit.frame, stop: hit.frame + 1 })),
      ]);
      await show($('#pose-viewer'), view([a, b], { autoplay: false }));
      ready();
    }

    form.addEventListener('submit', (ev) => { ev.preventDefault(); run().catch(fail); });
    status('Pick a frame (pause, step, scrub), then search.');
    ready('idle');
  }

  const PAGES = { browse, play, compare, search, poses };
  document.addEventListener('DOMContentLoaded', () => {
    const page = PAGES[document.body.dataset.page];
    if (page) page().catch(fail);
  });
})();
